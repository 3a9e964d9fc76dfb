//! Empty: its build-dependencies are what this crate is for (see Cargo.toml), and Cargo builds
//! build-dependencies only for a crate that has a build script.
fn main() {}
