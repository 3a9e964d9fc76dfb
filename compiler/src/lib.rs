//! The `.kin` compiler: source text → syntax tree → resolved, checked model → IR.
pub mod basis;
pub mod diagnostic;
pub mod ir;
pub mod syntax;
pub mod units;
