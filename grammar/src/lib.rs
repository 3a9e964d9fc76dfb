//! The `.kin` language's syntax: source text to a typed tree, knowing nothing of later stages.
//!
//! [`syntax`] parses with the pest grammar in `grammar/kin.pest` (the single source of truth
//! for the syntax) into the AST of [`syntax::ast`], recovering to report every syntax error;
//! [`format`](mod@format) lays a source out canonically (`kin fmt`); [`diagnostic`] is the one
//! [`Diagnostic`] type every stage of the compiler reports through, with its [`Span`].

pub mod diagnostic;
pub mod format;
pub mod syntax;

pub use diagnostic::{Diagnostic, Severity, Span};
