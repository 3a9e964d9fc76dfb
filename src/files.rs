//! The files a command writes: checked before any work (never an input, in a folder that
//! exists), and written atomically so that an interrupted command leaves the old file whole.

use std::path::Path;

use kin_data::output;

use crate::load::Failed;

/// Refuses, with exit 2, an output that is one of `inputs` or cannot be created.
pub fn check(output_path: &Path, inputs: &[&Path]) -> Result<(), Failed> {
    output::check_target(output_path, inputs).map_err(|e| {
        eprintln!("error: {e}");
        crate::errors::record("io", e.to_string(), Some(output_path), None);
        Failed::USAGE
    })
}

/// Replaces `path` with `contents` atomically ([`output::replace`]).
pub fn write(path: &Path, contents: &[u8]) -> Result<(), Failed> {
    output::replace(path, contents).map_err(|e| {
        eprintln!("error: cannot write `{}`: {e}", path.display());
        crate::errors::record("io", format!("cannot write: {e}"), Some(path), None);
        Failed::USAGE
    })?;
    crate::warnings::note(&format!(
        "wrote `{}` ({})",
        path.display(),
        crate::warnings::bytes(contents.len() as u64)
    ));
    Ok(())
}
