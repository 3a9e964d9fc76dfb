//! Standard tests and exchange formats: the ISO 230-2 (positioning), 230-3 (thermal) and
//! 230-4 (circular tests) evaluations, and URDF import.

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod dh;
pub mod iso230_2;
pub mod iso230_3;
pub mod iso230_4;
mod table;
pub mod urdf;
