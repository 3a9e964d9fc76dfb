//! Measurement files and the files kin writes.
//!
//! The layer under the model: [`data`] reads point, length and pose files against a compiled
//! machine (one table reader for every format) and writes them back; [`output`] replaces a file
//! atomically, so an interrupted write leaves the previous file whole; [`bounded_read`] reads a
//! text input with a size limit; [`history`] appends every fit to its model's history.

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod bounded_read;
pub mod data;
pub mod history;
pub mod output;
