//! `kin bench` runs and prints every figure (the figures themselves are a measurement, not
//! something a test can check).

use std::process::Command;

fn kin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("runs kin")
}

#[test]
fn bench_prints_rates_ratios_and_compile_time() {
    let out = kin(&[
        "bench",
        "examples/milling_5axis.kin",
        "--poses",
        "20",
        "--seconds",
        "0.05",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for expected in [
        "not a test",
        "interpreter",
        "JIT, one pose per call",
        "JIT, batch",
        "hand-written Rust",
        "baseline / JIT",
        "compile, source to callable functions",
        "interleaved rounds",
        "position rows",
        "b / pp",
        "C ABI",
        "c / b",
    ] {
        assert!(stdout.contains(expected), "missing `{expected}`:\n{stdout}");
    }
    // The C ABI measured on each of the three rows: its rate, ÷ per pose, ÷ the baseline.
    for row in ["six rows", "position rows", "error only"] {
        let line = stdout
            .lines()
            .find(|l| l.starts_with("error") && l.contains(row) && l.contains('.'))
            .unwrap_or_else(|| panic!("no `{row}` row:\n{stdout}"));
        let cells: Vec<&str> = line.split("  ").filter(|c| !c.trim().is_empty()).collect();
        let last: Vec<f64> = cells
            .iter()
            .rev()
            .take(2)
            .map(|c| c.trim().parse().unwrap_or(f64::NAN))
            .collect();
        assert!(
            last.iter().all(|r| r.is_finite() && *r > 0.0),
            "C ABI ratios of `{row}`: {line}"
        );
    }
    let out = kin(&[
        "bench",
        "examples/bridge_cmm.kin",
        "--poses",
        "20",
        "--seconds",
        "0.05",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && stdout.contains("no hand-written baseline"),
        "{stdout}"
    );
}

#[test]
fn bench_refuses_bad_options_and_machines() {
    assert_eq!(
        kin(&["bench", "examples/milling_5axis.kin", "--poses", "0"])
            .status
            .code(),
        Some(2)
    );
    assert_eq!(kin(&["bench", "examples/nope.kin"]).status.code(), Some(2));
    let dir = std::env::temp_dir().join(format!("kin-bench-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let bad = dir.join("bad.kin");
    std::fs::write(&bad, "machine m { axis X wobbly }").expect("writes");
    let out = kin(&["bench", bad.to_str().expect("utf-8")]);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("error"));
}
