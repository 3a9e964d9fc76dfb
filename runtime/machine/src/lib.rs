//! What a machine's controller applies: a fitted model turned into tables.
//!
//! [`component_errors`] samples each axis's parametric errors, [`axis_table`] the joint
//! corrections along an axis, and [`controller_tables`] writes them in controllers' formats.

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod axis_table;
pub mod component_errors;
pub mod controller_tables;
