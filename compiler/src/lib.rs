//! The `.kin` compiler: source text → syntax tree → resolved, checked model → IR.
//!
//! The public surface is small: [`compile`] a source into an [`ir::Machine`] with a
//! [`SourceMap`] back to the text, or the [`Diagnostic`]s explaining why not; [`bind_params`]
//! loads a separate `params { … }` file onto a compiled machine.
// `!(x > 0.0)` is written on purpose throughout: it is also true for NaN, which must fail the
// same checks as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod basis;
mod check;
pub mod ir;
mod lower;
mod params;
mod resolve;
pub mod units;

// The syntax layer (its own crate, which `kin fmt` and the language server can use alone),
// re-exported so that one crate serves a caller of the whole front end.
pub use kin_syntax::{diagnostic, format, syntax};

pub use diagnostic::{Diagnostic, Severity, Span};
pub use lower::{compile, Compiled, Output, SourceMap};

/// Binds a parameter file (`params { … }`) onto a compiled machine.
pub fn bind_params(machine: &mut ir::Machine, source: &str) -> Vec<Diagnostic> {
    match syntax::parse_params(source) {
        Ok(block) => params::bind(machine, &block),
        Err(d) => vec![d],
    }
}
