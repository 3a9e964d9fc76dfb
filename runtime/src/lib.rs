//! The `.kin` runtime.
