//! The `.kin` runtime.
pub mod data;
pub mod diagnose;
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
