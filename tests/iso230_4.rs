//! `kin iso230-4` and `kin iso230-2 --html/--model` end to end: a ball bar simulated by
//! `kin simulate` on a machine with a known squareness gives the G derived by hand, its lengths
//! fit back to the squareness, and the polar plot and the ISO 230-2 plot render in a browser.

mod common;

use std::fmt::Write as _;
use std::path::Path;

use common::{kin, scratch, screenshot};

/// A two-axis positioning machine: Y carries X, and the Y carriage's yaw `Y.rz` rotates X's
/// travel — a squareness error between the axes.
const MODEL: &str = "machine xy_table {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis Y prismatic along y range 0 mm .. 500 mm
    axis X prismatic along x range 0 mm .. 500 mm
    tool chain {
        Y moving
        X moving
        tool spindle
    }
    workpiece chain {
        workpiece
    }
    errors {
        Y.rz = const     // squareness of X to Y
    }
}
";

const SQUARENESS_URAD: f64 = 20.0;
const RADIUS_MM: f64 = 150.0;
const CENTRE_MM: (f64, f64) = (250.0, 250.0);

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn ok(out: &std::process::Output, what: &str) {
    assert!(
        out.status.success(),
        "{what}: {}\n{}",
        text(&out.stderr),
        text(&out.stdout)
    );
}

/// A CSV as a header and rows of cells (the files here have no quotes), comments skipped.
fn table(csv: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let mut lines = csv
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'));
    let header = lines
        .next()
        .expect("a header")
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

fn col(header: &[String], name: &str) -> usize {
    header
        .iter()
        .position(|h| h == name || h.starts_with(&format!("{name}[")))
        .unwrap_or_else(|| panic!("no column {name} in {header:?}"))
}

/// Ball-bar samples every 3° round the circle, counter-clockwise then clockwise, simulated
/// by kin as lengths from the centre pose; returned as an ISO 230-4 test file.
fn simulated_test(dir: &Path, noise: &str) -> String {
    let model = dir.join("xy.kin");
    std::fs::write(&model, MODEL).expect("model");
    let truth = dir.join("truth.params");
    std::fs::write(
        &truth,
        format!("params {{\n    Y.rz = [{SQUARENESS_URAD}] urad\n}}\n"),
    )
    .expect("truth");
    let mut poses = String::from("X_1[mm],Y_1[mm],X_2[mm],Y_2[mm]\n");
    let mut samples = Vec::new();
    for ccw in [true, false] {
        for i in 0..120 {
            let deg = if ccw {
                3.0 * i as f64
            } else {
                360.0 - 3.0 * i as f64
            };
            let (s, c) = deg.to_radians().sin_cos();
            let _ = writeln!(
                poses,
                "{},{},{:.12},{:.12}",
                CENTRE_MM.0,
                CENTRE_MM.1,
                CENTRE_MM.0 + RADIUS_MM * c,
                CENTRE_MM.1 + RADIUS_MM * s
            );
            samples.push((deg, ccw));
        }
    }
    let poses_path = dir.join("poses.csv");
    std::fs::write(&poses_path, poses).expect("poses");
    let sim = dir.join(format!("sim{noise}.csv"));
    let mut args = vec![
        "simulate",
        model.to_str().expect("utf-8"),
        "--params",
        truth.to_str().expect("utf-8"),
        "--poses",
        poses_path.to_str().expect("utf-8"),
        "-o",
        sim.to_str().expect("utf-8"),
    ];
    if !noise.is_empty() {
        args.extend(["--noise", noise, "--seed", "11"]);
    }
    ok(&kin(&args), "simulate");
    let (header, rows) = table(&std::fs::read_to_string(&sim).expect("simulated"));
    let dl = col(&header, "dL");
    assert!(
        header[dl].contains("[um]") || header[dl] == "dL",
        "{header:?}"
    );
    assert_eq!(rows.len(), samples.len());
    let mut out = format!(
        "# simulated ball bar\n# radius: {RADIUS_MM} mm\n# plane: X,Y\n# feed: 1000 mm/min\nangle[deg],deviation[um],direction\n"
    );
    for (row, (deg, ccw)) in rows.iter().zip(&samples) {
        let _ = writeln!(out, "{deg},{},{}", row[dl], if *ccw { "ccw" } else { "cw" });
    }
    out
}

fn number(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut v = v;
    for p in path {
        v = match p.parse::<usize>() {
            Ok(i) => &v[i],
            Err(_) => &v[*p],
        };
    }
    v.as_f64()
        .unwrap_or_else(|| panic!("{path:?} is not a number: {v}"))
}

/// The squareness α turns the circle into an oval `d = (α R / 2) sin 2θ`: G = α R in each
/// direction and both together, no centre offset, no radius error, no hysteresis.
#[test]
fn a_squareness_gives_the_g_derived_by_hand_and_fits_back_from_the_lengths() {
    let dir = scratch("squareness");
    let test = dir.join("ballbar.csv");
    std::fs::write(&test, simulated_test(&dir, "")).expect("test file");
    let out = kin(&[
        "iso230-4",
        test.to_str().expect("utf-8"),
        "--format",
        "json",
    ]);
    ok(&out, "iso230-4");
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(json["unit"], "m");
    assert_eq!(number(&json, &["setup", "radius"]), RADIUS_MM * 1e-3);
    let g = SQUARENESS_URAD * 1e-6 * RADIUS_MM * 1e-3;
    // The exact transforms differ from the first-order oval by (αR)²/R ≈ 6e-14 m; 3° sampling
    // hits the peaks at 45°.
    for dirn in ["ccw", "cw", "both"] {
        let f = |k: &str| number(&json, &["runs", "0", dirn, k]);
        assert!((f("g") - g).abs() < 1e-11, "{dirn}: G {} vs {g}", f("g"));
        assert!(f("radius_error").abs() < 1e-11, "{dirn}");
        for i in ["0", "1"] {
            let c = number(&json, &["runs", "0", dirn, "centre", i]);
            assert!(c.abs() < 1e-11, "{dirn}: centre {c}");
        }
        assert!((f("f_max") - g / 2.0).abs() < 1e-11, "{dirn}: F max");
        assert!((f("f_min") + g / 2.0).abs() < 1e-11, "{dirn}: F min");
    }
    assert!(number(&json, &["runs", "0", "h"]).abs() < 1e-11);
    // The human table says the same in µm.
    let out = kin(&["iso230-4", test.to_str().expect("utf-8")]);
    ok(&out, "iso230-4 human");
    let shown = text(&out.stdout);
    assert!(
        shown.contains("G  circular deviation") && shown.contains("3.000"),
        "{shown}"
    );

    // With noise, as lengths, fitted: the squareness comes back.
    let noisy = dir.join("ballbar_noisy.csv");
    std::fs::write(&noisy, simulated_test(&dir, "0.2um")).expect("noisy test");
    let bars = dir.join("bars.csv");
    let page = dir.join("ballbar.html");
    let out = kin(&[
        "iso230-4",
        noisy.to_str().expect("utf-8"),
        "--lengths",
        bars.to_str().expect("utf-8"),
        "--centre",
        "X=250mm,Y=250mm",
        "--html",
        page.to_str().expect("utf-8"),
    ]);
    ok(&out, "iso230-4 --lengths");
    // The length file read as spec/data.md describes it: point 1 the centre, point 2 on the
    // nominal circle, one artifact, dL the reading.
    let (header, rows) = table(&std::fs::read_to_string(&bars).expect("lengths"));
    let (noisy_header, noisy_rows) = table(&std::fs::read_to_string(&noisy).expect("noisy"));
    let dev = col(&noisy_header, "deviation");
    assert_eq!(rows.len(), noisy_rows.len());
    let c = |r: &Vec<String>, n: &str| -> f64 { r[col(&header, n)].parse().expect("number") };
    for (r, n) in rows.iter().zip(&noisy_rows) {
        assert_eq!((c(r, "X_1"), c(r, "Y_1")), CENTRE_MM);
        let (dx, dy) = (c(r, "X_2") - CENTRE_MM.0, c(r, "Y_2") - CENTRE_MM.1);
        assert!(((dx * dx + dy * dy).sqrt() - RADIUS_MM).abs() < 1e-9);
        assert_eq!(r[col(&header, "artifact")], "bar1");
        let reading: f64 = n[dev].parse().expect("deviation");
        assert!((c(r, "dL") - reading).abs() < 1e-12);
        for d in ["dir_X_2", "dir_Y_2"] {
            assert!(["+1", "-1"].contains(&r[col(&header, d)].as_str()));
        }
    }
    let fit = dir.join("fit.json");
    let out = kin(&[
        "fit",
        dir.join("xy.kin").to_str().expect("utf-8"),
        bars.to_str().expect("utf-8"),
        "-o",
        fit.to_str().expect("utf-8"),
    ]);
    ok(&out, "fit");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).expect("fit")).expect("FIT.json");
    let sq = report["coefficients"]
        .as_array()
        .expect("coefficients")
        .iter()
        .find(|c| c["name"].as_str().is_some_and(|n| n.starts_with("Y.rz")))
        .unwrap_or_else(|| panic!("no Y.rz in {}", report["coefficients"]));
    let (value, se) = (
        sq["value"].as_f64().expect("value"),
        sq["se"].as_f64().expect("se"),
    );
    assert_eq!(sq["unit"], "urad");
    assert!(
        (value - SQUARENESS_URAD).abs() < 4.0 * se && se < 0.5,
        "squareness {value} ± {se} urad, simulated {SQUARENESS_URAD}"
    );
    // The page: figures and a polar plot with both directions, rendered by a browser.
    let html = std::fs::read_to_string(&page).expect("page");
    assert!(html.contains("G circular deviation, ccw") && html.contains("H circular hysteresis"));
    assert_eq!(html.matches("<svg").count(), 1, "one polar plot");
    assert!(!html.contains("NaN") && !html.contains("inf"));
    screenshot(&page, &dir, 1400, 20_000);
}

#[test]
fn outputs_are_checked_before_any_work() {
    let dir = scratch("outputs");
    let test = dir.join("t.csv");
    std::fs::write(
        &test,
        "angle,deviation,direction\n0,1,ccw\n120,2,ccw\n240,1,ccw\n",
    )
    .expect("test");
    let t = test.to_str().expect("utf-8");
    // An output naming the input is refused, and the input survives.
    let out = kin(&["iso230-4", t, "--html", t]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert!(std::fs::read_to_string(&test)
        .expect("kept")
        .starts_with("angle"));
    // Lengths without the radius or the plane: a usage error naming what is missing.
    let bars = dir.join("bars.csv");
    let out = kin(&[
        "iso230-4",
        t,
        "--lengths",
        bars.to_str().expect("utf-8"),
        "--centre",
        "X=0mm,Y=0mm",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("the plane is needed"),
        "{}",
        text(&out.stderr)
    );
    assert!(!bars.exists());
    // A bad cell: exit 1, located.
    std::fs::write(&test, "angle,deviation,direction\n0,1,ccw\n120,two,ccw\n").expect("test");
    let out = kin(&["iso230-4", t]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("line 3, column 5"),
        "{}",
        text(&out.stderr)
    );
}

/// A run along X of the machine above with a known pitch error of the model's own form and a
/// reversal it lacks: the model with the right error fits (p large), without it does not.
#[test]
fn iso230_2_plot_and_lack_of_fit_of_a_model() {
    let dir = scratch("iso230_2");
    // X.tx = linear(X): a scale error the model holds; the run adds 0.4 µm of repeatability
    // noise (fixed pseudo-random values) and, in the second run, a 3 µm reversal.
    let model = dir.join("x.kin");
    std::fs::write(
        &model,
        MODEL.replace(
            "Y.rz = const     // squareness of X to Y",
            "X.tx = linear(X)",
        ),
    )
    .expect("model");
    let params = dir.join("p.params");
    std::fs::write(&params, "params {\n    X.tx = [5] um\n}\n").expect("params");
    let mut state = 12345u64;
    let mut noise = move || {
        // A small LCG, summed to a roughly normal value of σ ≈ 0.4 µm.
        (0..12)
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 11) as f64 / (1u64 << 53) as f64
            })
            .sum::<f64>()
            * 0.4
            - 2.4
    };
    let mut fits = String::from("target[mm],deviation[um],direction,cycle\n");
    let mut lacks = fits.clone();
    for cycle in 1..=5 {
        for i in 0..=10 {
            for up in [true, false] {
                let x = 50.0 * i as f64;
                let n = noise();
                // linear(X) is 2s − 1 over the range 0 … 500 mm: ±5 µm at its ends.
                let systematic = 5.0 * (2.0 * x / 500.0 - 1.0);
                let sign = if up { "+1" } else { "-1" };
                let _ = writeln!(fits, "{x},{},{sign},{cycle}", systematic + n);
                let reversal = if up { 1.5 } else { -1.5 };
                let _ = writeln!(lacks, "{x},{},{sign},{cycle}", systematic + reversal + n);
            }
        }
    }
    let mut p = Vec::new();
    for (name, run) in [("fits", &fits), ("lacks", &lacks)] {
        let path = dir.join(format!("{name}.csv"));
        std::fs::write(&path, run).expect("run");
        let page = dir.join(format!("{name}.html"));
        let out = kin(&[
            "iso230-2",
            path.to_str().expect("utf-8"),
            "--html",
            page.to_str().expect("utf-8"),
            "--model",
            model.to_str().expect("utf-8"),
            "--fit",
            params.to_str().expect("utf-8"),
            "--axis",
            "X",
            "--at",
            "Y=100mm",
            "--format",
            "json",
        ]);
        ok(&out, name);
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
        let test = &json["lack_of_fit"]["test"];
        assert_eq!(json["lack_of_fit"]["component"], "ex");
        assert_eq!(test["groups"], 22, "{test}");
        assert_eq!(test["dof_pure"], 88.0);
        assert_eq!(test["dof_lack"], 22.0);
        p.push(test["p"].as_f64().expect("p"));
        let html = std::fs::read_to_string(&page).expect("page");
        assert!(html.contains("x̄ ± 2s") && html.matches("<svg").count() == 1);
        if name == "fits" {
            screenshot(&page, &dir, 1200, 20_000);
        }
    }
    assert!(p[0] > 0.01, "the right model is rejected: p = {}", p[0]);
    assert!(
        p[1] < 1e-6,
        "a model without the reversal passes: p = {}",
        p[1]
    );
    // The human output says so in words.
    let out = kin(&[
        "iso230-2",
        dir.join("lacks.csv").to_str().expect("utf-8"),
        "--model",
        model.to_str().expect("utf-8"),
        "--fit",
        params.to_str().expect("utf-8"),
        "--axis",
        "X",
    ]);
    ok(&out, "human");
    assert!(
        text(&out.stdout).contains("the model does not explain the run"),
        "{}",
        text(&out.stdout)
    );
    // An axis held outside its range by --at, and targets beyond the moved axis's range, are
    // warned of (W0801) as every command that reads poses does; --strict makes them an error.
    let beyond = dir.join("beyond.csv");
    std::fs::write(&beyond, fits.replace("\n500,", "\n700,")).expect("run");
    let args = |run: &std::path::Path, at: &str| {
        vec![
            "iso230-2".to_string(),
            run.display().to_string(),
            "--model".into(),
            model.display().to_string(),
            "--fit".into(),
            params.display().to_string(),
            "--axis".into(),
            "X".into(),
            "--at".into(),
            at.into(),
        ]
    };
    let fits_csv = dir.join("fits.csv");
    for (run, at, says) in [
        (
            &fits_csv,
            "Y=9999mm",
            "Y is held outside its declared range 0 .. 500 mm (at 9999 mm)",
        ),
        (
            &beyond,
            "Y=100mm",
            "10 of 110 approaches put X outside its declared range 0 .. 500 mm (first at line",
        ),
    ] {
        let a = args(run, at);
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        let out = kin(&a);
        ok(&out, at);
        let err = text(&out.stderr);
        assert!(
            err.contains("warning[W0801]") && err.contains(says),
            "{err}"
        );
        let mut strict = a.clone();
        strict.push("--strict");
        let out = kin(&strict);
        assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
        assert!(text(&out.stderr).contains("error[W0801]"));
    }
    let a = args(&fits_csv, "Y=100mm");
    let a: Vec<&str> = a.iter().map(String::as_str).collect();
    let out = kin(&a);
    ok(&out, "in range");
    assert!(
        !text(&out.stderr).contains("W0801"),
        "{}",
        text(&out.stderr)
    );
}

/// The bundled example (`examples/data/ballbar_xy.csv`, README): its figures are those of its
/// simulated truth, and its lengths fit back to that truth.
#[test]
fn the_bundled_ball_bar_example_gives_its_truth() {
    let dir = scratch("example");
    let out = kin(&[
        "iso230-4",
        "examples/data/ballbar_xy.csv",
        "--format",
        "json",
    ]);
    ok(&out, "example");
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    // Squareness 20 µrad and X scale 8 µm/m on R = 150 mm: an oval of half-heights 1.5 µm
    // (sin 2θ) and 0.6 µm (cos 2θ), G = 2·√(1.5² + 0.6²) = 3.23 µm, radius error 0.6 µm; the
    // 0.15 µm noise widens G by at most some 6σ.
    let g = number(&json, &["runs", "0", "both", "g"]);
    assert!((3.23e-6..3.23e-6 + 6.0 * 0.15e-6).contains(&g), "G {g}");
    let c = number(&json, &["runs", "0", "both", "radius_error"]);
    assert!((c - 0.6e-6).abs() < 0.05e-6, "radius error {c}");
    let bars = dir.join("bars.csv");
    ok(
        &kin(&[
            "iso230-4",
            "examples/data/ballbar_xy.csv",
            "--lengths",
            bars.to_str().expect("utf-8"),
            "--centre",
            "X=250mm,Y=250mm",
        ]),
        "lengths",
    );
    let out = kin(&[
        "fit",
        "examples/xy_table.kin",
        bars.to_str().expect("utf-8"),
        "--format",
        "json",
    ]);
    ok(&out, "fit");
    let fit: serde_json::Value = serde_json::from_slice(&out.stdout).expect("FIT.json");
    for (name, truth) in [("Y.rz", 20.0), ("X.tx", 2.0)] {
        let c = fit["coefficients"]
            .as_array()
            .expect("coefficients")
            .iter()
            .find(|c| c["name"].as_str().is_some_and(|n| n.starts_with(name)))
            .unwrap_or_else(|| panic!("no {name}"));
        let (v, se) = (
            c["value"].as_f64().expect("v"),
            c["se"].as_f64().expect("se"),
        );
        assert!(
            (v - truth).abs() < 4.0 * se,
            "{name}: {v} ± {se}, truth {truth}"
        );
    }
}
