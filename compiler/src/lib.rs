//! The `.kin` compiler: source text → syntax tree → resolved, checked model → IR.
pub mod basis;
pub mod ir;
pub mod units;
