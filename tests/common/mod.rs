//! What several end-to-end test files share: running the real binary, scratch folders, and the
//! small three-axis CMM model most of them simulate and fit.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// Runs `kin` with `args` from the crate's root.
pub fn kin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("kin runs")
}

/// A fresh folder for one test, inside this process's scratch folder.
pub fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir()
        .join(format!(
            "kin-{}-{}",
            env!("CARGO_CRATE_NAME"),
            std::process::id()
        ))
        .join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch folder");
    dir
}

pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Standard output, after checking that `kin` succeeded.
pub fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "exit {:?}\n{}\n{}",
        out.status.code(),
        text(&out.stdout),
        text(&out.stderr)
    );
    text(&out.stdout)
}

/// A bridge-like CMM with three prismatic axes and a small error model: a spline, a constant
/// rotation and two linear terms (`ERRORS` is its `errors` block's body).
pub fn cmm3(errors: &str) -> String {
    format!(
        "machine cmm3 {{
    task measure
    units {{ length mm, error um, tilt urad }}
    axis X prismatic along x range 0 mm .. 800 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    tool chain {{
        X moving
        Y moving
        Z moving at (0, 0, 500) mm
        tool probe at (0, 0, -100) mm
    }}
    errors {{
{errors}    }}
}}
"
    )
}

/// The body of `cmm3`'s usual `errors` block.
pub const CMM3_ERRORS: &str = "        X.tx = spline(X, knots 2)
        X.rz = const
        Y.ty = linear(Y)
        Z.tz = linear(Z)
";

/// Values for `CMM3_ERRORS`, as a `params` block.
pub const CMM3_TRUTH: &str = "params {
    X.tx = [3, -2, 1, 0.5] um
    X.rz[0] = 4 urad
    Y.ty[0] = 1.5 um
    Z.tz[0] = 2 um
}
";

/// Simulates `n` poses of `model` at `params` with `extra` options into `out`.
pub fn simulate(model: &str, params: &str, n: usize, seed: u64, extra: &[&str], out: &str) {
    let n = n.to_string();
    let seed = seed.to_string();
    let mut args = vec![
        "simulate", model, "--params", params, "--sample", &n, "--seed", &seed, "-o", out,
    ];
    args.extend_from_slice(extra);
    ok(&kin(&args));
}
