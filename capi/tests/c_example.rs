//! The C example program (`examples/eval.c`) built against the library, run on a bundled
//! machine, and its numbers checked against the Rust API's to 1e-12.
//!
//! Cargo builds `libkin_capi.so` next to this test's `deps` folder (the crate's `cdylib`); the
//! program is compiled with the C compiler on the PATH (`$CC`, else `cc`, else `gcc`). Without
//! one the test says so and passes: CI machines have one.

use std::path::{Path, PathBuf};
use std::process::Command;

use kin_model::Model;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The folder holding `libkin_capi.so`: the profile folder above this test's `deps`.
fn library_dir() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let deps = exe.parent()?;
    let name = format!(
        "{}kin_capi{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    );
    // `cargo build` copies the library up from `deps`, `cargo test` builds it in `deps` only:
    // the newer of the two is this build's.
    let modified = |d: &Path| {
        std::fs::metadata(d.join(&name))
            .and_then(|m| m.modified())
            .ok()
    };
    let found = [deps.parent()?, deps]
        .into_iter()
        .filter_map(|d| Some((modified(d)?, d)))
        .max_by_key(|(t, _)| *t)
        .map(|(_, d)| d.to_path_buf());
    found
}

/// `LD_LIBRARY_PATH` with `lib` first.
fn library_path(lib: &Path) -> std::ffi::OsString {
    let mut dirs = vec![lib.to_path_buf()];
    if let Some(old) = std::env::var_os("LD_LIBRARY_PATH") {
        dirs.extend(std::env::split_paths(&old));
    }
    std::env::join_paths(dirs).unwrap_or_default()
}

fn c_compiler() -> Option<String> {
    let candidates = std::env::var("CC")
        .ok()
        .into_iter()
        .chain(["cc".to_string(), "gcc".to_string()]);
    candidates.into_iter().find(|cc| {
        Command::new(cc)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    })
}

/// The records of the program's output: tag, state, numbers.
fn records(text: &str) -> Vec<(String, usize, Vec<f64>)> {
    text.lines()
        .filter(|l| !l.starts_with("counts"))
        .map(|l| {
            let mut words = l.split_whitespace();
            let tag = words.next().expect("tag").to_string();
            let k = words.next().expect("state").parse().expect("state index");
            let values = words.map(|w| w.parse().expect("number")).collect();
            (tag, k, values)
        })
        .collect()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1e-9)
}

#[test]
fn the_c_example_matches_the_rust_api() {
    let Some(cc) = c_compiler() else {
        eprintln!(
            "SKIPPED: no C compiler (cc, gcc or $CC) on the PATH, so the C example is not built"
        );
        return;
    };
    let lib = library_dir()
        .expect("libkin_capi next to the test binary (cargo builds the cdylib with the crate)");
    let out_dir = std::env::temp_dir().join(format!("kin-capi-example-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).expect("temp dir");
    let exe = out_dir.join("eval");
    let capi = root().join("capi");
    let build = Command::new(&cc)
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-O1"])
        .arg(capi.join("examples/eval.c"))
        .arg("-I")
        .arg(capi.join("include"))
        .arg("-L")
        .arg(&lib)
        .arg("-lkin_capi")
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .arg("-o")
        .arg(&exe)
        .output()
        .expect("runs the C compiler");
    assert!(
        build.status.success(),
        "{cc} failed:\n{}",
        String::from_utf8_lossy(&build.stderr)
    );

    let machine = root().join("examples/bridge_cmm.kin");
    let params = root().join("examples/data/bridge_cmm_truth.params");
    let run = Command::new(&exe)
        // Cargo's own library path lists the profile folder too, where an older `cargo build`
        // may have left a stale copy: the library this test found comes first.
        .env("LD_LIBRARY_PATH", library_path(&lib))
        .arg(&machine)
        .arg(&params)
        .output()
        .expect("runs the example");
    let _ = std::fs::remove_dir_all(&out_dir);
    let stdout = String::from_utf8_lossy(&run.stdout);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        run.status.success(),
        "the example failed:\n{stdout}\n{stderr}"
    );
    assert!(
        stderr.contains("status 2"),
        "the wrong length is refused: {stderr}"
    );

    let source = std::fs::read_to_string(&machine).expect("machine");
    let model = Model::compile(&source)
        .expect("compiles")
        .with_params(&std::fs::read_to_string(&params).expect("params"))
        .expect("binds");
    let m = model.machine();
    let n = model.coefficients();
    assert!(
        stdout.starts_with(&format!(
            "counts {} {} {} {} {n}\n",
            model.axes(),
            model.inputs(),
            model.lags(),
            model.tools()
        )),
        "{stdout}"
    );

    // The same states, built as the program builds them.
    let states: Vec<kin_model::StateBuf> = (0..4)
        .map(|k| {
            let t = (k as f64 + 1.0) / 5.0;
            let mut s = model.state();
            for (a, axis) in m.axes.iter().enumerate() {
                s.q[a] = axis.range[0] + t * (axis.range[1] - axis.range[0]);
                s.dirs[a] = if (k + a) % 2 == 1 { -1.0 } else { 1.0 };
            }
            for (i, input) in m.inputs.iter().enumerate() {
                let [lo, hi] = match input.range {
                    Some(r) => r,
                    None if input.absolute => [291.15, 295.15],
                    None => [0.0, 4.0],
                };
                s.inputs[i] = lo + t * (hi - lo);
            }
            for (l, lag) in m.lags.iter().enumerate() {
                s.lags[l] = s.inputs[lag.input];
            }
            s.time = 60.0 * k as f64;
            s.tool = k % model.tools();
            s
        })
        .collect();

    let got = records(&stdout);
    assert_eq!(got.len(), 4 * 6, "{stdout}");
    let mut compared = 0;
    for (tag, k, values) in got {
        let s = states[k].get();
        let expected: Vec<f64> = match tag.as_str() {
            "err" | "jerr" | "batch" => {
                let mut e = [0.0; 6];
                model.eval(&s, model.beta(), &mut e).expect("eval");
                e.to_vec()
            }
            "jac" => {
                let (mut e, mut j) = ([0.0; 6], vec![0.0; 6 * n]);
                model
                    .eval_jacobian(&s, model.beta(), &mut e, &mut j)
                    .expect("eval");
                j
            }
            "pbatch" => {
                let (mut e, mut j) = (vec![0.0; 3], vec![0.0; 3 * n]);
                model
                    .eval_jacobian_observed(
                        &s,
                        model.beta(),
                        kin_model::engine::Observed::POSITION,
                        &mut e,
                        &mut j,
                    )
                    .expect("eval");
                e.into_iter().chain(j).collect()
            }
            "nominal" => {
                let mut j = vec![0.0; 6 * model.axes()];
                model
                    .nominal_jacobian(&s, &mut j)
                    .expect("nominal")
                    .position
                    .iter()
                    .copied()
                    .collect()
            }
            other => panic!("unexpected record `{other}`"),
        };
        assert_eq!(values.len(), expected.len(), "{tag} {k}");
        for (i, (a, b)) in values.iter().zip(&expected).enumerate() {
            assert!(
                close(*a, *b),
                "{tag} {k}[{i}]: C printed {a:e}, Rust gives {b:e}"
            );
            compared += 1;
        }
        if tag == "err" {
            assert!(
                values.iter().any(|v| *v != 0.0),
                "the bound parameters act: {values:?}"
            );
        }
    }
    eprintln!("the C example's {compared} numbers agree with the Rust API to 1e-12");
}

/// `examples/compensate.c`: the compiled compensation function through the C ABI gives the
/// Rust API's corrections, and refuses a command outside the range and an overlapping output.
#[test]
fn the_c_compensation_example_matches_the_rust_api() {
    let Some(cc) = c_compiler() else {
        eprintln!(
            "SKIPPED: no C compiler (cc, gcc or $CC) on the PATH, so the C example is not built"
        );
        return;
    };
    let lib = library_dir().expect("libkin_capi next to the test binary");
    let out_dir = std::env::temp_dir().join(format!("kin-capi-compensate-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).expect("temp dir");
    let exe = out_dir.join("compensate");
    let capi = root().join("capi");
    let build = Command::new(&cc)
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-O1"])
        .arg(capi.join("examples/compensate.c"))
        .arg("-I")
        .arg(capi.join("include"))
        .arg("-L")
        .arg(&lib)
        .arg("-lkin_capi")
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .arg("-o")
        .arg(&exe)
        .output()
        .expect("runs the C compiler");
    assert!(
        build.status.success(),
        "{cc} failed:\n{}",
        String::from_utf8_lossy(&build.stderr)
    );
    let machine = root().join("examples/milling_5axis.kin");
    let run = Command::new(&exe)
        // Cargo's own library path lists the profile folder too, where an older `cargo build`
        // may have left a stale copy: the library this test found comes first.
        .env("LD_LIBRARY_PATH", library_path(&lib))
        .arg(&machine)
        .output()
        .expect("runs the example");
    let _ = std::fs::remove_dir_all(&out_dir);
    let stdout = String::from_utf8_lossy(&run.stdout);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        run.status.success(),
        "the example failed:\n{stdout}\n{stderr}"
    );
    assert!(
        stderr.contains("outside the range: status 12") && stderr.contains("dq over q: status 11"),
        "{stderr}"
    );

    let source = std::fs::read_to_string(&machine).expect("machine");
    let mut model = Model::compile(&source).expect("compiles");
    let n = model.coefficients();
    let beta: Vec<f64> = (0..n).map(|j| 1e-6 * ((j % 7) as f64 - 3.0)).collect();
    model.set_beta(&beta).expect("β");
    let m = model.machine().clone();
    let comp = model
        .compensator(kin_model::compensate::Options::pose(&m))
        .expect("compensator");
    let mut compared = 0;
    let mut worst = 0.0f64;
    for k in 0..4 {
        let t = (k as f64 + 1.0) / 5.0;
        let mut s = model.state();
        for (a, axis) in m.axes.iter().enumerate() {
            s.q[a] = axis.range[0] + t * (axis.range[1] - axis.range[0]);
            s.dirs[a] = if (k + a) % 2 == 1 { -1.0 } else { 1.0 };
        }
        for (i, input) in m.inputs.iter().enumerate() {
            let [lo, hi] = match input.range {
                Some(r) => r,
                None if input.absolute => [291.15, 295.15],
                None => [0.0, 4.0],
            };
            s.inputs[i] = lo + t * (hi - lo);
        }
        for (l, lag) in m.lags.iter().enumerate() {
            s.lags[l] = s.inputs[lag.input];
        }
        s.time = 60.0 * k as f64;
        s.tool = k % model.tools();
        let mut dq = vec![0.0; model.axes()];
        let done = comp.compensate(&s.get(), &mut dq).expect("compensates");
        // The closed loop through the C ABI: the C program's corrections applied to the exact
        // machine whose errors are the model's (every frame's error a finite transform) leave
        // only products of two errors, nanometres, of micrometres before.
        let c_dq: Vec<f64> = stdout
            .lines()
            .find(|l| l.starts_with(&format!("dq {k} ")))
            .map(|l| {
                l.split_whitespace()
                    .skip(2)
                    .map(|w| w.parse().expect("number"))
                    .collect()
            })
            .unwrap_or_else(|| panic!("no `dq {k}` in\n{stdout}"));
        let (before, after) = exact_before_after(&m, &beta, &s.get(), &c_dq);
        assert!(before > 1e-6, "pose {k}: a real error: {before:e}");
        assert!(after < 10e-9, "pose {k}: {after:e} m left of {before:e}");
        worst = worst.max(after);
        for (tag, expected) in [
            ("dq", dq.clone()),
            ("before", done.before.to_vec()),
            ("after", done.after.to_vec()),
            ("rank", vec![done.rank as f64]),
        ] {
            let line = stdout
                .lines()
                .find(|l| l.starts_with(&format!("{tag} {k} ")))
                .unwrap_or_else(|| panic!("no `{tag} {k}` in\n{stdout}"));
            let values: Vec<f64> = line
                .split_whitespace()
                .skip(2)
                .map(|w| w.parse().expect("number"))
                .collect();
            assert_eq!(values.len(), expected.len(), "{line}");
            for (a, b) in values.iter().zip(&expected) {
                assert!(
                    close(*a, *b),
                    "{tag} {k}: C printed {a:e}, Rust gives {b:e}"
                );
                compared += 1;
            }
        }
        assert!(
            dq.iter().any(|d| d.abs() > 1e-7),
            "a real correction: {dq:?}"
        );
    }
    eprintln!(
        "the C compensation example's {compared} numbers agree with the Rust API; its corrections \
         leave at most {:.3} nm on the exact machine",
        worst * 1e9
    );
}

/// The exact machine with coefficients `beta` (every frame's error a finite transform): its
/// position error at the commanded pose, and at the pose moved by `dq` against the commanded
/// location (m).
fn exact_before_after(
    m: &kin_compiler::ir::Machine,
    beta: &[f64],
    s: &kin_model::interp::State,
    dq: &[f64],
) -> (f64, f64) {
    use kin_model::exact;
    use kin_model::kinematics::{FrameErrors, Pose};
    let mut it = kin_model::interp::Interpreter::new(m).expect("interpreter");
    let mut errors = FrameErrors::zeros(m);
    let pose = Pose {
        q: s.q,
        tool: s.tool,
        tool_offset: s.tool_offset,
    };
    let target = exact::nominal_transform(m, &pose).expect("nominal");
    it.frame_errors(s, beta, &mut errors).expect("errors");
    let actual = exact::actual_transform(m, &pose, &errors).expect("actual");
    let before = exact::location_error(&target, &actual)
        .fixed_rows::<3>(0)
        .norm();
    let q: Vec<f64> = s.q.iter().zip(dq).map(|(a, d)| a + d).collect();
    let moved = kin_model::interp::State { q: &q, ..*s };
    it.frame_errors(&moved, beta, &mut errors).expect("errors");
    let actual = exact::actual_transform(m, &Pose { q: &q, ..pose }, &errors).expect("actual");
    let after = exact::location_error(&target, &actual)
        .fixed_rows::<3>(0)
        .norm();
    (before, after)
}
