//! The kinematic model of a compiled machine, evaluated.
//!
//! [`kinematics`] is the first-order model of thesis §2.3 and [`exact`] the finite transforms
//! it is checked against; [`interp`] (the interpreter) and [`jit`] (Cranelift) are the two
//! engines that evaluate a model's error and its Jacobians, and must agree ([`engine`] picks
//! one); [`states`] and [`lag`] turn measured poses and temperature histories into engine
//! inputs; [`compensate`] solves for joint corrections (§2.3.5).
//!
//! To embed a model in a program, start at [`Model`] (the [`embed`] module).

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod compensate;
pub mod embed;
pub mod engine;
pub mod exact;
pub mod interp;
pub mod jit;
pub mod kinematics;
pub mod lag;
pub mod states;

pub use embed::{Model, RowsBuf, StateBuf};
pub use engine::Engine;
