//! No code: see this crate's `Cargo.toml`. It exists so that the workspace's build and the
//! Python package's switch on the same features of the crates they share, and so reuse one
//! another's compiled artifacts.
