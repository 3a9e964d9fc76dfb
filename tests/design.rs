//! `kin design` end to end: the thesis' 2-D CMM (§4.4, Table 4.1) with 400 mm ball bars.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::{Command, Output};

const CMM: &str = "machine cmm2d {
    task measure
    units { length mm, angle deg, error um, tilt urad }
    axis Y prismatic along y range 0 mm .. 500 mm
    axis X prismatic along x range 0 mm .. 500 mm
    tool chain {
        Y moving
        X moving
        tool probe
    }
    workpiece chain {
        workpiece
    }
    errors {
        X.tx = linear(X)     // scale error of X
        Y.ty = linear(Y)     // scale error of Y
        Y.rz = const         // squareness of X to Y
    }
}
";

fn kin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .output()
        .expect("kin runs")
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("kin-design-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

/// A length file of 400 mm bars given by first sphere and angle.
fn bars(bars: &[(f64, f64, f64)]) -> String {
    let mut s = String::from("X_1[mm],Y_1[mm],X_2[mm],Y_2[mm]\n");
    for &(x, y, a) in bars {
        let (sn, cs) = a.to_radians().sin_cos();
        let _ = writeln!(s, "{x},{y},{:.9},{:.9}", x + 400.0 * cs, y + 400.0 * sn);
    }
    s
}

/// The thesis' candidates: first sphere on a 50 mm grid, 15° steps, both spheres inside.
fn candidates() -> Vec<(f64, f64, f64)> {
    let mut out = Vec::new();
    for i in 0..=10 {
        for j in 0..=10 {
            for k in 0..24 {
                let (x, y, a) = (50.0 * i as f64, 50.0 * j as f64, 15.0 * k as f64);
                let (s, c) = a.to_radians().sin_cos();
                let inside = |v: f64| (-1e-9..=500.0 + 1e-9).contains(&v);
                if inside(x + 400.0 * c) && inside(y + 400.0 * s) {
                    out.push((x, y, a));
                }
            }
        }
    }
    out
}

fn json(o: &Output) -> serde_json::Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("json")
}

fn fig(v: &serde_json::Value, name: &str) -> f64 {
    v["figures"][name].as_f64().expect(name)
}

#[test]
fn design_chooses_a_d_optimal_plan_and_scores_the_thesis_designs() {
    let d = dir("table41");
    let machine = d.join("cmm2d.kin");
    std::fs::write(&machine, CMM).expect("write");
    let cands = d.join("candidates.csv");
    std::fs::write(&cands, bars(&candidates())).expect("write");
    let plan = d.join("plan.csv");
    let m = machine.to_str().expect("utf8");
    let c = cands.to_str().expect("utf8");
    let p = plan.to_str().expect("utf8");

    let chosen = json(&kin(&[
        "design",
        m,
        "--candidates",
        c,
        "-n",
        "6",
        "-o",
        p,
        "--format",
        "json",
    ]));
    assert_eq!(chosen["rank"], 3);
    assert_eq!(chosen["chosen"], 6);
    // A D-optimal design's largest prediction variance is the number of coefficients.
    assert!((fig(&chosen, "maximum_prediction_variance") - 3.0).abs() < 1e-6);
    let written = std::fs::read_to_string(&plan).expect("plan");
    assert_eq!(written.lines().count(), 7, "{written}");

    // Scoring the written plan gives the same figures.
    let again = json(&kin(&[
        "design",
        m,
        "--evaluate",
        p,
        "--candidates",
        c,
        "--format",
        "json",
    ]));
    let best = fig(&again, "det_root");
    assert!((best - fig(&chosen, "det_root")).abs() < 1e-9 * best);

    // Designs 1 and 2 of Table 4.1: their det^(1/3) relative to the optimum is the thesis'
    // 2.98/2.50 and 2.60/2.50 (the absolute value depends on the coefficients' units), and
    // their maximum prediction variances are 9.00 and 4.00.
    let score = |angles: &[(f64, f64, f64)]| {
        let f = d.join("d.csv");
        std::fs::write(&f, bars(angles)).expect("write");
        json(&kin(&[
            "design",
            m,
            "--evaluate",
            f.to_str().expect("utf8"),
            "--candidates",
            c,
            "--format",
            "json",
        ]))
    };
    let d1 = score(&[
        (50.0, 250.0, 0.0),
        (50.0, 250.0, 0.0),
        (100.0, 100.0, 45.0),
        (100.0, 100.0, 45.0),
        (250.0, 50.0, 90.0),
        (250.0, 50.0, 90.0),
    ]);
    let d2 = score(&[
        (50.0, 250.0, 0.0),
        (50.0, 250.0, 0.0),
        (100.0, 100.0, 45.0),
        (100.0, 400.0, 315.0),
        (250.0, 50.0, 90.0),
        (250.0, 50.0, 90.0),
    ]);
    let round2 = |v: f64| (v * 100.0).round() / 100.0;
    assert_eq!(round2(2.50 * fig(&d1, "det_root") / best), 2.98);
    assert_eq!(round2(2.50 * fig(&d2, "det_root") / best), 2.60);
    assert_eq!(round2(fig(&d1, "maximum_prediction_variance")), 9.00);
    assert_eq!(round2(fig(&d2, "maximum_prediction_variance")), 4.00);
}

#[test]
fn a_plan_that_cannot_separate_terms_says_which_and_what_it_determines() {
    let d = dir("blind");
    let machine = d.join("cmm2d.kin");
    std::fs::write(&machine, CMM).expect("write");
    // Bars along x only: the x scale is determined, the y scale and squareness are not seen.
    let f = d.join("x_only.csv");
    std::fs::write(&f, bars(&[(0.0, 0.0, 0.0), (50.0, 100.0, 0.0)])).expect("write");
    let o = kin(&[
        "design",
        machine.to_str().expect("utf8"),
        "--evaluate",
        f.to_str().expect("utf8"),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("determines 1 of 3"), "{out}");
    assert!(out.contains("Y.ty") && out.contains("Y.rz"), "{out}");
    assert!(!out.contains("det^(1/p)"), "{out}");
}

#[test]
fn design_without_candidates_or_plan_is_a_usage_error() {
    let d = dir("usage");
    let machine = d.join("cmm2d.kin");
    std::fs::write(&machine, CMM).expect("write");
    let o = kin(&["design", machine.to_str().expect("utf8")]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn generated_ball_bar_candidates_are_the_thesis_grid() {
    let d = dir("generate");
    let machine = d.join("cmm2d.kin");
    std::fs::write(&machine, CMM).expect("write");
    let out = d.join("gen.csv");
    let o = kin(&[
        "design",
        machine.to_str().expect("utf8"),
        "--generate",
        "ballbar",
        "--plane",
        "X,Y",
        "--length",
        "400mm",
        "--step",
        "50mm",
        "--angle-step",
        "15deg",
        "-o",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&out).expect("written");
    let rows: Vec<Vec<f64>> = text
        .lines()
        .skip(2)
        .map(|l| l.split(',').map(|v| v.parse().expect("number")).collect())
        .collect();
    assert_eq!(rows.len(), candidates().len());
    for r in &rows {
        // X_1, Y_1, X_2, Y_2 in the machine's declared axis order (Y first): a 400 mm bar.
        let (dy, dx) = (r[2] - r[0], r[3] - r[1]);
        assert!((dx.hypot(dy) - 400.0).abs() < 1e-6, "{r:?}");
        assert!(
            r.iter().all(|v| (-1e-9..=500.0 + 1e-9).contains(v)),
            "{r:?}"
        );
    }
}

#[test]
fn check_plan_takes_artifacts_placement_and_length_out() {
    let d = dir("check-plan");
    let machine = d.join("cmm2d.kin");
    std::fs::write(&machine, CMM).expect("write");
    let m = machine.to_str().expect("utf8");
    // One bar of unknown length along x, then along y: only the difference of the two scales
    // is seen; the squareness is not seen at all.
    let bar = d.join("bar.csv");
    std::fs::write(
        &bar,
        "X_1[mm],Y_1[mm],X_2[mm],Y_2[mm],artifact\n0,0,400,0,bar\n0,0,0,400,bar\n",
    )
    .expect("write");
    let o = kin(&["check", m, "--plan", bar.to_str().expect("utf8")]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("determines 1 of 3"), "{out}");
    // The summary: per component, the unseen ones per frame, the combination.
    assert!(
        out.contains("X.tx EXX           0 of 1: 1 only in combination with Y.ty"),
        "{out}"
    );
    assert!(out.contains("    X.tx[0] - Y.ty[0]\n"), "{out}");
    assert!(out.contains("Y.rz "), "{out}");
    assert!(
        !out.contains("coefficient              σ"),
        "the detail is behind --detail: {out}"
    );
    let o = kin(&[
        "check",
        m,
        "--plan",
        bar.to_str().expect("utf8"),
        "--detail",
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        out.contains("cannot separate X.tx[0], Y.ty[0]; determined: X.tx[0] - Y.ty[0]"),
        "{out}"
    );
    assert!(out.contains("not determined at all: Y.rz[0]"), "{out}");
    assert!(
        !out.contains("e-1 "),
        "an undetermined coefficient has no σ: {out}"
    );
    // A plate of unknown placement at four corners: scales and squareness are all seen.
    let plate = d.join("plate.csv");
    std::fs::write(
        &plate,
        "X[mm],Y[mm],artifact\n0,0,p\n400,0,p\n0,400,p\n400,400,p\n",
    )
    .expect("write");
    let v = json(&kin(&[
        "check",
        m,
        "--plan",
        plate.to_str().expect("utf8"),
        "--format",
        "json",
    ]));
    assert_eq!(v["rank"], 3);
    assert_eq!(v["figures"]["observations"], 12);
    for t in v["terms"].as_array().expect("terms") {
        assert!(
            t["sigma_per_unit_noise"].as_f64().is_some_and(|s| s > 0.0),
            "{t}"
        );
    }
}

#[test]
fn a_min_norm_fit_marks_undetermined_coefficients_and_diagnose_accepts_the_model() {
    let d = dir("min-norm");
    let machine = d.join("cmm2d.kin");
    std::fs::write(&machine, CMM).expect("write");
    let m = machine.to_str().expect("utf8");
    // Bars along x only (one repeated): the y scale and the squareness are not observed.
    let poses = d.join("poses.csv");
    std::fs::write(
        &poses,
        bars(&[
            (0.0, 0.0, 0.0),
            (50.0, 100.0, 0.0),
            (0.0, 200.0, 0.0),
            (100.0, 300.0, 0.0),
            (0.0, 0.0, 0.0),
        ]),
    )
    .expect("write");
    let truth = d.join("truth.params");
    std::fs::write(
        &truth,
        "params {\n X.tx[0] = 3\n Y.ty[0] = 2\n Y.rz[0] = 5\n}\n",
    )
    .expect("write");
    let data = d.join("data.csv");
    let o = kin(&[
        "simulate",
        m,
        "--poses",
        poses.to_str().expect("utf8"),
        "--params",
        truth.to_str().expect("utf8"),
        "--noise",
        "0.1um",
        "-o",
        data.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report = d.join("fit.json");
    let data = data.to_str().expect("utf8");
    let o = kin(&[
        "fit",
        m,
        data,
        "--min-norm",
        "-o",
        report.to_str().expect("utf8"),
    ]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("Y.ty EYY         [um] undetermined"), "{out}");
    assert!(
        out.contains("Y.rz             [urad] undetermined"),
        "{out}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    for c in v["coefficients"].as_array().expect("coefficients") {
        let seen = c["name"] == "X.tx[0]";
        assert_eq!(c["se"].is_null(), !seen, "{c}");
        assert_eq!(c["note"].is_null(), seen, "{c}");
    }
    assert_eq!(v["estimability"]["rank"], 1);
    let groups = v["estimability"]["groups"].as_array().expect("groups");
    assert_eq!(groups.len(), 2, "{groups:?}");
    assert!(out.contains("not determined at all: Y.ty[0]"), "{out}");
    let o = kin(&["diagnose", m, data]);
    assert!(
        o.status.success(),
        "diagnose refused: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// A 3-axis measuring machine: X's positioning spline and straightness in y, Y's scale, the
/// XY squareness, Z's scale.
const CMM3: &str = "machine cmm3 {
    task measure
    units { length mm, angle deg, error um, tilt urad }
    axis Y prismatic along y range 0 mm .. 500 mm
    axis X prismatic along x range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    tool chain {
        Y moving
        X moving
        Z moving
        tool probe
    }
    workpiece chain {
        workpiece
    }
    errors {
        X.tx = spline(X, knots 3)          // positioning of X
        X.ty = straightness(X, knots 3)    // straightness of X in y
        Y.ty = linear(Y)                   // scale of Y
        Y.rz = const                       // squareness of X to Y
        Z.tz = linear(Z)                   // scale of Z
    }
}
";

/// A file's header names (units stripped) and its data rows as cells, read by the rules of
/// spec/data.md (comment lines start with `#`, the first other line is the header).
fn read_csv(path: &std::path::Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).expect("written");
    let mut lines = text.lines().filter(|l| !l.trim_start().starts_with('#'));
    let header = lines
        .next()
        .expect("header")
        .split(',')
        .map(|h| h.split('[').next().unwrap_or(h).trim().to_string())
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(|c| c.trim().to_string()).collect())
        .collect();
    (header, rows)
}

fn cell(header: &[String], row: &[String], name: &str) -> f64 {
    let k = header.iter().position(|h| h == name).expect(name);
    row[k].parse().expect("number")
}

/// The coefficients `kin check --plan` finds determined, by name.
fn determined(machine: &str, plan: &std::path::Path) -> Vec<(String, bool)> {
    let v = json(&kin(&[
        "check",
        machine,
        "--plan",
        plan.to_str().expect("utf8"),
        "--format",
        "json",
    ]));
    v["terms"]
        .as_array()
        .expect("terms")
        .iter()
        .map(|t| {
            (
                t["name"].as_str().expect("name").to_string(),
                t["determined"].as_bool().expect("flag"),
            )
        })
        .collect()
}

fn all_determined(d: &[(String, bool)], prefix: &str) -> bool {
    let of: Vec<_> = d.iter().filter(|(n, _)| n.starts_with(prefix)).collect();
    !of.is_empty() && of.iter().all(|(_, ok)| *ok)
}

fn none_determined(d: &[(String, bool)], prefix: &str) -> bool {
    let of: Vec<_> = d.iter().filter(|(n, _)| n.starts_with(prefix)).collect();
    !of.is_empty() && of.iter().all(|(_, ok)| !*ok)
}

#[test]
fn a_step_gauge_along_x_determines_its_positioning_but_not_its_straightness() {
    let d = dir("stepgauge");
    let machine = d.join("cmm3.kin");
    std::fs::write(&machine, CMM3).expect("write");
    let m = machine.to_str().expect("utf8");
    let out = d.join("gauge.csv");
    let o = kin(&[
        "design",
        m,
        "--generate",
        "stepgauge",
        "--axis",
        "X",
        "--length",
        "420mm",
        "--pitch",
        "20mm",
        "--step",
        "60mm",
        "--levels",
        "2",
        "-o",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (h, rows) = read_csv(&out);
    // First faces at 0, 60, 120, 180 (180 + 420 = 600 is the end of the range), 21 distances
    // each, on the 2 × 2 lines of Y and Z at the ends of their ranges.
    assert_eq!(rows.len(), 4 * 21 * 4);
    for r in &rows {
        let (x1, x2) = (cell(&h, r, "X_1"), cell(&h, r, "X_2"));
        assert!(
            (0.0..=600.0).contains(&x1) && (0.0..=600.0).contains(&x2),
            "{r:?}"
        );
        let k = (x2 - x1) / 20.0;
        assert!(
            (k - k.round()).abs() < 1e-9 && (1.0..=21.0).contains(&k),
            "{r:?}"
        );
        assert_eq!(cell(&h, r, "Y_1"), cell(&h, r, "Y_2"));
        assert_eq!(cell(&h, r, "Z_1"), cell(&h, r, "Z_2"));
        assert!([0.0, 500.0].contains(&cell(&h, r, "Y_1")), "{r:?}");
        assert!([-400.0, 0.0].contains(&cell(&h, r, "Z_1")), "{r:?}");
    }
    let det = determined(m, &out);
    assert!(all_determined(&det, "X.tx"), "{det:?}");
    assert!(none_determined(&det, "X.ty"), "{det:?}");
    assert!(
        none_determined(&det, "Y.ty") && none_determined(&det, "Z.tz"),
        "{det:?}"
    );
    // A design over the candidates chooses rows of the file.
    let plan = d.join("plan.csv");
    let o = kin(&[
        "design",
        m,
        "--candidates",
        out.to_str().expect("utf8"),
        "-n",
        "8",
        "-o",
        plan.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (_, chosen) = read_csv(&plan);
    assert_eq!(chosen.len(), 8);
    assert!(chosen.iter().all(|c| rows.contains(c)));
}

#[test]
fn plates_in_the_xy_plane_determine_the_xy_squareness_and_scales_not_z() {
    let d = dir("plate");
    let machine = d.join("cmm3.kin");
    std::fs::write(&machine, CMM3).expect("write");
    let m = machine.to_str().expect("utf8");
    let out = d.join("plate.csv");
    let o = kin(&[
        "design",
        m,
        "--generate",
        "plate",
        "--plane",
        "X,Y",
        "--length",
        "300mm",
        "--pitch",
        "100mm",
        "--step",
        "100mm",
        "--angle-step",
        "30deg",
        "-o",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (h, rows) = read_csv(&out);
    let label = h
        .iter()
        .position(|c| c == "artifact")
        .expect("artifact column");
    let mut labels: Vec<&str> = rows.iter().map(|r| r[label].as_str()).collect();
    labels.dedup();
    assert!(labels.len() > 4, "several placements: {labels:?}");
    for l in &labels {
        let features: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r[label] == *l)
            .map(|r| (cell(&h, r, "X"), cell(&h, r, "Y")))
            .collect();
        // A 4 × 4 grid 100 mm apart: rigid, whatever its rotation, and inside the ranges.
        assert_eq!(features.len(), 16, "{l}");
        let (a, b, c) = (features[0], features[1], features[4]);
        let dist = |p: (f64, f64), q: (f64, f64)| (p.0 - q.0).hypot(p.1 - q.1);
        assert!((dist(a, b) - 100.0).abs() < 1e-6 && (dist(a, c) - 100.0).abs() < 1e-6);
        assert!((dist(a, features[15]) - 300.0 * 2f64.sqrt()).abs() < 1e-6);
        for (x, y) in features {
            assert!((-1e-9..=600.0 + 1e-9).contains(&x) && (-1e-9..=500.0 + 1e-9).contains(&y));
        }
    }
    let det = determined(m, &out);
    for t in ["X.tx", "Y.ty", "Y.rz"] {
        assert!(all_determined(&det, t), "{t}: {det:?}");
    }
    // Z stays at the middle of its range: its scale is not seen.
    assert!(none_determined(&det, "Z.tz"), "{det:?}");
}

/// An R-test on a rotary table: X, Y, Z follow a sphere on the table as C turns.
const ROTARY: &str = "machine rtest {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis X prismatic along x range -300 mm .. 300 mm
    axis Y prismatic along y range -300 mm .. 300 mm
    axis Z prismatic along z range -100 mm .. 300 mm
    axis C revolute about z continuous
    tool chain {
        X moving
        Y moving
        Z moving
        tool probe
    }
    workpiece chain {
        C moving
        workpiece
    }
    errors {
        X.tx = linear(X)    // scale of X
        Y.ty = linear(Y)    // scale of Y
        Z.tz = linear(Z)    // scale of Z
    }
}
";

#[test]
fn an_r_test_follows_each_sphere_and_sees_the_ellipticity_not_the_size() {
    let d = dir("rtest");
    let machine = d.join("rotary.kin");
    std::fs::write(&machine, ROTARY).expect("write");
    let m = machine.to_str().expect("utf8");
    let out = d.join("rtest.csv");
    let o = kin(&[
        "design",
        m,
        "--generate",
        "rtest",
        "--sphere",
        "150,0,50",
        "--sphere",
        "0mm,250mm,50mm",
        "--angle-step",
        "30deg",
        "-o",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (h, rows) = read_csv(&out);
    let label = h
        .iter()
        .position(|c| c == "artifact")
        .expect("artifact column");
    // Sphere 1 (radius 150) at all 12 angles; sphere 2 (radius 250) too: both inside ±300.
    assert_eq!(rows.len(), 24);
    for r in &rows {
        let (x, y, z, c) = (
            cell(&h, r, "X"),
            cell(&h, r, "Y"),
            cell(&h, r, "Z"),
            cell(&h, r, "C"),
        );
        // The tool is at the sphere: on its circle about the C axis, at its height.
        let radius = if r[label].starts_with("s1") {
            150.0
        } else {
            250.0
        };
        assert!((x.hypot(y) - radius).abs() < 1e-6, "{r:?}");
        assert!((z - 50.0).abs() < 1e-9, "{r:?}");
        assert!((0.0..360.0).contains(&c));
    }
    // Each sweep's sphere has an unknown placement: a circle scaled alike in x and y is the
    // same circle about another sphere position, so only the difference of the two scales is
    // seen (an R-test sees the ellipticity, not the size); the spheres stay at one height, so
    // Z's scale is not seen at all.
    let o = kin(&[
        "check",
        m,
        "--plan",
        out.to_str().expect("utf8"),
        "--detail",
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        text.contains("cannot separate X.tx[0], Y.ty[0]; determined: X.tx[0] - Y.ty[0]"),
        "{text}"
    );
    assert!(text.contains("not determined at all: Z.tz[0]"), "{text}");
    // A sphere no angle can reach (outside the ranges) gives no rows; none at all is an error.
    let o = kin(&[
        "design",
        m,
        "--generate",
        "rtest",
        "--sphere",
        "500,0,0",
        "-o",
        d.join("none.csv").to_str().expect("utf8"),
    ]);
    assert_eq!(o.status.code(), Some(2));
}

/// A step gauge on one line of the 5-axis example (all other axes held) sees the error along
/// the line at its faces and nothing else: a function of Y at 11 positions, lengths between
/// them, so at most 10 directions of the 173 coefficients — whatever the spline bases make of
/// them. The rank is decided once (`kin check` on the model's own sampling decides it the same
/// way); an eigenvalue line drawn relative to the largest used to keep rounding noise as 25
/// "determined" directions here.
#[test]
fn a_step_gauge_on_one_line_determines_no_more_than_its_faces_can_show() {
    let d = dir("stepgauge-one-line");
    let root = env!("CARGO_MANIFEST_DIR");
    let m = format!("{root}/examples/milling_5axis.kin");
    let gauge = d.join("gauge.csv");
    let o = kin(&[
        "design",
        &m,
        "--generate",
        "stepgauge",
        "-o",
        gauge.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (h, rows) = read_csv(&gauge);
    let mut faces: Vec<i64> = rows
        .iter()
        .flat_map(|r| [cell(&h, r, "Y_1"), cell(&h, r, "Y_2")])
        .map(|y| (y * 1e3).round() as i64)
        .collect();
    faces.sort_unstable();
    faces.dedup();
    let v = json(&kin(&[
        "check",
        &m,
        "--plan",
        gauge.to_str().expect("utf8"),
        "--format",
        "json",
    ]));
    let rank = v["rank"].as_u64().expect("rank") as usize;
    assert!(
        (1..faces.len()).contains(&rank),
        "{rank} directions from {} face positions",
        faces.len()
    );
}

/// A 3-axis mill with the 21 component errors of ISO 230-1 (splines along each axis and the
/// three squarenesses): a step gauge along X measured at one height and one y sees EXX and
/// EBX only through the gauge's Abbe arm. The summary fits on a screen, names what is not
/// seen by kin's and ISO 230-1's names, and states the Abbe combinations with their arm.
#[test]
fn a_step_gauge_plan_fits_on_a_screen_in_iso_terms() {
    let d = dir("step-gauge-summary");
    let machine = d.join("mill3.kin");
    let mut errors = String::new();
    for axis in ["X", "Y", "Z"] {
        for c in ["tx", "ty", "tz", "rx", "ry", "rz"] {
            errors.push_str(&format!("        {axis}.{c} = spline({axis}, knots 3)\n"));
        }
    }
    errors.push_str("        Y.rz += const\n        Z.rx += const\n        Z.ry += const\n");
    let source = format!(
        "machine mill3 {{
    task position
    units {{ length mm, error um, tilt urad }}
    axis Y prismatic along -y range 0 mm .. 400 mm
    axis X prismatic along -x range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    workpiece chain {{
        Y fixed at (0, 200, 0) mm
        X fixed at (300, 0, 100) mm
        workpiece at (0, 0, 0) mm
    }}
    tool chain {{
        Z moving at (0, 0, 600) mm
        tool spindle at (0, 0, -150) mm
    }}
    errors {{
{errors}    }}
}}
"
    );
    std::fs::write(&machine, source).expect("write");
    let m = machine.to_str().expect("utf8");
    let gauge = d.join("gauge.csv");
    let g = gauge.to_str().expect("utf8");
    let o = kin(&[
        "design",
        m,
        "--generate",
        "stepgauge",
        "--axis",
        "X",
        "-o",
        g,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = kin(&["check", m, "--plan", g]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let lines = out.lines().count();
    assert!(lines <= 30, "{lines} lines:\n{out}");
    assert!(out.contains("X.tx EXX"), "{out}");
    assert!(out.contains("Y.ty EYY ("), "{out}");
    assert!(out.contains("Z.tz EZZ ("), "{out}");
    // EXX seen through the arm between the gauge and X's frame: translation + arm × rotation.
    assert!(
        out.lines()
            .any(|l| l.trim_start().starts_with("X.tx[") && l.contains(" mm × X.r")),
        "{out}"
    );
    // The detail is all there behind --detail.
    let o = kin(&["check", m, "--plan", g, "--detail"]);
    let detail = String::from_utf8_lossy(&o.stdout);
    assert!(detail.lines().count() > 3 * lines, "{detail}");
}
