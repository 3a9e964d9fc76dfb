//! Replays every input kept for the fuzz targets — the corpus (`fuzz/corpus/TARGET/`) and the
//! minimised crashes (`fuzz/regressions/TARGET/`) — through the same harness functions libFuzzer
//! runs (`fuzz/src/lib.rs`), on the stable toolchain, so that `cargo test` keeps every crash the
//! fuzzer once found fixed. Fuzzing itself: `fuzz/run.sh` (see `fuzz/README.md`).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

#[allow(dead_code)]
#[path = "../fuzz/src/lib.rs"]
mod harness;

/// The files of `fuzz/corpus/<target>` and `fuzz/regressions/<target>`, sorted.
fn inputs(target: &str) -> Vec<PathBuf> {
    let fuzz = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    let mut out: Vec<PathBuf> = ["corpus", "regressions"]
        .iter()
        .filter_map(|dir| std::fs::read_dir(fuzz.join(dir).join(target)).ok())
        .flat_map(|entries| entries.flatten().map(|e| e.path()))
        .filter(|p| p.is_file() && p.file_name().is_some_and(|n| n != ".gitkeep"))
        .collect();
    out.sort();
    out
}

/// Runs every kept input of `target`; fails naming each input that panics.
fn replay(target: &str, harness: fn(&[u8])) {
    let inputs = inputs(target);
    assert!(!inputs.is_empty(), "no kept inputs for `{target}`");
    let failed: Vec<String> = inputs
        .iter()
        .filter(|path| {
            let bytes = std::fs::read(path)
                .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
            catch_unwind(AssertUnwindSafe(|| harness(&bytes))).is_err()
        })
        .map(|p| p.display().to_string())
        .collect();
    assert!(
        failed.is_empty(),
        "{} of {} inputs of `{target}` panic:\n{}",
        failed.len(),
        inputs.len(),
        failed.join("\n")
    );
}

#[test]
fn kin_source_inputs_do_not_panic() {
    replay("kin_source", harness::kin_source);
}

#[test]
fn measurement_csv_inputs_do_not_panic() {
    replay("measurement_csv", harness::measurement_csv);
}

#[test]
fn robot_description_inputs_do_not_panic() {
    replay("robot_description", harness::robot_description);
}

#[test]
fn lsp_inputs_do_not_panic() {
    replay("lsp", harness::lsp);
}

#[test]
fn fit_json_inputs_do_not_panic() {
    replay("fit_json", harness::fit_json);
}

#[test]
fn capi_inputs_do_not_panic() {
    replay("capi", harness::capi);
}
