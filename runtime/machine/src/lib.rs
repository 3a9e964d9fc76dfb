//! What a machine's controller applies: a fitted model turned into corrections and tables.
//!
//! [`corrections`] gives the joint corrections at commanded poses; [`component_errors`] samples
//! each axis's parametric errors, [`axis_table`] the joint corrections along an axis, and
//! [`controller_tables`] writes them in controllers' formats; [`table_set`] makes a format's
//! whole set of tables over a [`grid`] of poses, with what they leave.

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod axis_table;
pub mod component_errors;
pub mod controller_tables;
pub mod corrections;
pub mod grid;
pub mod table_set;
