//! The `.kin` runtime.
//!
//! To embed a model in a program, start at [`Model`] (the [`embed`] module).
pub mod bench;
pub mod data;
pub mod diagnose;
pub mod embed;
pub mod engine;
pub mod exact;
pub mod fit;
pub mod history;
pub mod identify;
pub mod interp;
pub mod jit;
pub mod kinematics;
pub mod lag;
pub mod simulate;
pub mod states;

pub use embed::{Model, RowsBuf, StateBuf};
pub use engine::Engine;
