//! The streamed fit (`fit::stream`) against the fit that holds its rows: the same files give the
//! same numbers (on one thread with block boundaries anywhere; on several, where the blocks
//! are those the held fit takes, and to rounding elsewhere), and a bad file the same error.

use std::path::PathBuf;

use kin_compiler::{compile, Compiled};
use kin_data::data::{self, Groups, Observations, ReadOptions, WriteOptions};
use kin_estimate::fit::{self, report, DataSet, FitError, Options};
use kin_estimate::simulate::{self, sample_points};
use kin_model::interp::Interpreter;

const CMM: &str = r#"
machine cmm3 {
    task measure
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 800 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    tool chain {
        X moving
        Y moving
        Z moving at (0, 0, 500) mm
        tool probe at (0, 0, -100) mm
        tool side at (60, 40, -100) mm
    }
    workpiece chain { workpiece }
    errors {
        X.tx = spline(X, knots 2)
        X.rz = const + linear(X)
        Y.ty = linear(Y) + backlash(Y)
        Y.tx = straightness(Y, knots 2)
        X.ry = const
        Y.rx = const
        Z.tz = linear(Z)
    }
}
"#;

fn machine() -> Compiled {
    let out = compile(CMM);
    out.compiled
        .unwrap_or_else(|| panic!("{:#?}", out.diagnostics))
}

/// Simulated points with noise and a few gross errors (so there are outliers), written to
/// `dir`; `artifacts` labels spread over the rows.
fn written(c: &Compiled, dir: &std::path::Path, n: usize, seed: u64, artifacts: usize) -> PathBuf {
    let beta: Vec<f64> = c
        .machine
        .coefficients
        .iter()
        .enumerate()
        .map(|(j, co)| co.unit.scale * ((j as f64 * 0.37).sin() * 4.0))
        .collect();
    let mut poses = sample_points(&c.machine, n, seed);
    if artifacts > 0 {
        poses.rows.artifact = Some(Groups {
            of_row: (0..n).map(|r| Some((r % artifacts) as u32)).collect(),
            labels: (0..artifacts).map(|a| format!("plate{a}")).collect(),
        });
    }
    let options = simulate::Options {
        noise: 0.5e-6,
        seed: seed + 1,
        artifact_shift: 50e-6,
        artifact_rotation: 20e-6,
        ..simulate::Options::default()
    };
    let mut obs = simulate::simulate(&c.machine, &beta, &Observations::Points(poses), &options)
        .expect("simulate");
    if let Observations::Points(p) = &mut obs {
        if let Some(ex) = p.observed[0].as_mut() {
            for r in (7..ex.len()).step_by(997) {
                ex[r] += 30e-6;
            }
        }
    }
    let path = dir.join(format!("points{seed}.csv"));
    data::write_file(&path, &c.machine, &obs, &WriteOptions::default()).expect("write");
    path
}

fn on(threads: usize) -> Options {
    Options {
        threads,
        ..Options::default()
    }
}

fn held(c: &Compiled, paths: &[PathBuf], options: &Options) -> (Vec<DataSet>, fit::FitResult) {
    let files: Vec<DataSet> = paths
        .iter()
        .map(|p| DataSet {
            path: p.clone(),
            observations: data::read_file(p, &c.machine, &ReadOptions::default()).expect("read"),
        })
        .collect();
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    let r = fit::fit(c, &mut it, &files, &[], options, &mut |_, _| {}).expect("fit");
    (files, r)
}

fn streamed(
    c: &Compiled,
    paths: &[PathBuf],
    chunk: usize,
    options: &Options,
) -> Result<fit::stream::Streamed, FitError> {
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    fit::stream::fit_in_chunks(
        c,
        &mut it,
        paths,
        &ReadOptions::default(),
        options,
        chunk,
        &mut |_, _| {},
    )
}

fn close(a: f64, b: f64) -> bool {
    near(a, b, 0.0)
}

/// Within 1e-10 relative, or `floor` absolute (a residual of nearly zero is rounding).
fn near(a: f64, b: f64, floor: f64) -> bool {
    a == b || (a - b).abs() <= 1e-10 * a.abs().max(b.abs()) + floor
}

/// The streamed fit read `chunk` rows at a time against the held fit, on `threads` threads:
/// every number within 1e-10 (a row's residual within 1e-10 σ), and the reports equal when
/// `exact`.
fn same_report(c: &Compiled, paths: &[PathBuf], chunk: usize, threads: usize, exact: bool) {
    let options = on(threads);
    let (files, r) = held(c, paths, &options);
    let s = streamed(c, paths, chunk, &options).expect("streamed fit");
    assert_eq!(r.rows, s.result.rows);
    assert_eq!(r.solution.rank, s.result.solution.rank);
    assert!(
        close(r.sigma, s.result.sigma),
        "{} vs {}",
        r.sigma,
        s.result.sigma
    );
    for (a, b) in r.solution.beta.iter().zip(&s.result.solution.beta) {
        assert!(close(*a, *b), "β {a} vs {b}");
    }
    // Every row's statistics: the streamed fit keeps them all below MAX_RESIDUALS rows.
    assert_eq!(r.residuals.len(), s.result.residuals.len());
    for (a, b) in r.residuals.iter().zip(&s.result.residuals) {
        assert_eq!(a.meta, b.meta);
        for (x, y, floor) in [
            (a.residual, b.residual, 1e-10 * r.sigma),
            (a.leverage, b.leverage, 1e-15),
            (a.studentized, b.studentized, 1e-10),
            // Cook's distance squares the residual (of threshold ≈ 1).
            (a.cook, b.cook, 1e-15),
        ] {
            assert!(near(x, y, floor), "line {}: {x} vs {y}", a.meta.line);
        }
    }
    let one = report::build(&c.machine, CMM, "interp", &files, &[], &r, &options);
    let two = report::build(
        &c.machine,
        CMM,
        "interp",
        &s.files,
        &[],
        &s.result,
        &options,
    );
    assert!(!one.outliers.is_empty(), "the gross errors are outliers");
    let json = |r: &report::FitReport| serde_json::to_value(r).expect("json");
    if exact {
        assert_eq!(json(&one), json(&two));
    }
}

#[test]
fn a_streamed_fit_equals_the_held_fit_whatever_the_block_size() {
    let c = machine();
    let dir = tempfile::tempdir().expect("tempdir");
    let paths = vec![
        written(&c, dir.path(), 3000, 1, 0),
        written(&c, dir.path(), 1100, 2, 0),
    ];
    for chunk in [1, 97, 4096, 1 << 20] {
        same_report(&c, &paths, chunk, 1, true);
        // Two threads split each block of rows read in two: the held fit's blocks are the
        // files' first `CHUNK_ROWS` rows and so on, here each file whole.
        same_report(&c, &paths, chunk, 2, chunk >= 3000);
    }
}

#[test]
fn a_streamed_fit_places_artifacts_as_the_held_fit_does() {
    let c = machine();
    let dir = tempfile::tempdir().expect("tempdir");
    let paths = vec![written(&c, dir.path(), 2000, 3, 5)];
    same_report(&c, &paths, 333, 1, true);
    same_report(&c, &paths, 333, 2, false);
    same_report(&c, &paths, fit::stream::CHUNK_ROWS, 2, true);
}

#[test]
fn a_thin_artifact_is_reported_at_its_rows_as_by_the_held_fit() {
    let c = machine();
    let dir = tempfile::tempdir().expect("tempdir");
    // 1000 rows over 999 labels: label 0 has two rows, the others one each.
    let path = written(&c, dir.path(), 1000, 4, 999);
    let files = vec![DataSet {
        path: path.clone(),
        observations: data::read_file(&path, &c.machine, &ReadOptions::default()).expect("read"),
    }];
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    let held = fit::fit(
        &c,
        &mut it,
        &files,
        &[],
        &Options::default(),
        &mut |_, _| {},
    )
    .err()
    .map(|e| e.to_string());
    let streamed = streamed(&c, &[path], 64, &Options::default())
        .err()
        .map(|e| e.to_string());
    assert!(
        held.as_deref().is_some_and(|e| e.contains("too thinly")),
        "{held:?}"
    );
    assert_eq!(held, streamed);
}

#[test]
fn a_bad_cell_past_the_first_block_is_the_same_error_as_when_read_whole() {
    let c = machine();
    let dir = tempfile::tempdir().expect("tempdir");
    let path = written(&c, dir.path(), 500, 5, 0);
    let text = std::fs::read_to_string(&path).expect("read");
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let n = lines.len();
    for at in [n - 3, n - 100] {
        if let Some(line) = lines.get_mut(at) {
            *line = line.replacen(',', ",oops", 1);
        }
    }
    std::fs::write(&path, lines.join("\n") + "\n").expect("write");
    let whole = data::read_file(&path, &c.machine, &ReadOptions::default())
        .err()
        .map(|e| e.to_string());
    let streamed = streamed(&c, &[path], 50, &Options::default())
        .err()
        .map(|e| e.to_string());
    assert!(whole.is_some(), "the damaged file must not read");
    assert_eq!(whole, streamed);
}

#[test]
fn a_file_without_rows_or_with_a_bad_header_is_the_same_error_as_when_read_whole() {
    let c = machine();
    let dir = tempfile::tempdir().expect("tempdir");
    for (name, text) in [
        ("empty.csv", "# nothing\n"),
        ("header_only.csv", "X[mm],Y[mm],Z[mm],ex[um]\n"),
        ("bad_header.csv", "X[mm],Y[mm],Z[mm],ex[um],bogus\n"),
        (
            "bad_header_rows.csv",
            "X[mm],Y[mm],Z[mm],bogus,ex[um]\n1,2,-3,4,5\n",
        ),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, text).expect("write");
        let whole = data::read_file(&path, &c.machine, &ReadOptions::default())
            .err()
            .map(|e| e.to_string());
        let streamed = streamed(&c, &[path], 10, &Options::default())
            .err()
            .map(|e| e.to_string());
        assert!(whole.is_some(), "{name} must not read");
        assert_eq!(whole, streamed, "{name}");
    }
}
