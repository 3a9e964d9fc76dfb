//! The `.kin` runtime.
pub mod kinematics;
pub mod exact;
pub mod data;
pub mod interp;
pub mod lag;
pub mod states;
pub mod identify;
pub mod simulate;
pub mod engine;
pub mod jit;
pub mod fit;
pub mod diagnose;
pub mod history;
