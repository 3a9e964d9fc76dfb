//! `examples/embed.rs` runs: the embedding API's example, on the bundled CMM with its parameter
//! values, compiled into this test and run in-process.

#[allow(dead_code)]
#[path = "../examples/embed.rs"]
mod embed;

use std::path::Path;

#[test]
fn the_embedding_example_runs() {
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let summary = embed::run(
        &examples.join("bridge_cmm.kin"),
        Some(&examples.join("data/bridge_cmm_truth.params")),
    )
    .expect("the example runs");
    assert!(summary.coefficients > 0);
    assert!(summary.engines <= 1e-12, "{summary:?}");
    assert!(
        summary.reloaded_identical && summary.threads_agree,
        "{summary:?}"
    );
}

#[test]
fn the_embedding_example_runs_on_the_mill() {
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    let summary = embed::run(&examples.join("milling_5axis.kin"), None).expect("the example runs");
    assert_eq!(summary.coefficients, 173);
    assert!(
        summary.engines <= 1e-12 && summary.reloaded_identical && summary.threads_agree,
        "{summary:?}"
    );
}
