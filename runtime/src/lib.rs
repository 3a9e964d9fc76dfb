//! The `.kin` runtime.
pub mod kinematics;
pub mod exact;
pub mod data;
