//! The `.kin` runtime.
//!
//! To embed a model in a program, start at [`Model`] (the [`embed`] module).

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
pub mod axis_table;
// Benchmark code (`kin bench`, the hand-written baseline): only with the `bench` feature.
#[cfg(feature = "bench")]
pub mod bench;
pub mod bounded_read;
pub mod compensate;
pub mod component_errors;
pub mod controller_tables;
pub mod data;
pub mod design;
pub mod diagnose;
pub mod embed;
pub mod engine;
pub mod exact;
pub mod fit;
pub mod history;
pub mod identify;
pub mod interp;
pub mod iso230_2;
pub mod iso230_3;
pub mod iso230_4;
pub mod jit;
pub mod kinematics;
pub mod lag;
pub mod output;
pub mod plan;
pub mod predict;
mod rank_update;
pub mod simulate;
pub mod states;
pub mod urdf;

pub use embed::{Model, RowsBuf, StateBuf};
pub use engine::Engine;
