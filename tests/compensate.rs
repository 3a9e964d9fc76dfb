//! End-to-end runs of `kin compensate` and `kin correct`: a machine with known errors is
//! simulated and fitted by the binary, then compensated; the LinuxCNC tables are read back
//! by a parser written from LinuxCNC's documentation of `COMP_FILE` (lines of three numbers:
//! nominal, position reached moving in +, position reached moving in −; nominals ascending;
//! at most 256 lines).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn kin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .output()
        .expect("kin runs")
}

fn dir() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kin-compensate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}\n{}",
        text(&out.stdout),
        text(&out.stderr)
    );
}

/// Data rows of a CSV written by kin, as numbers per named column (unit stripped).
fn column(path: &Path, name: &str) -> Vec<f64> {
    let s = std::fs::read_to_string(path).expect("csv");
    let mut lines = s.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let k = header
        .iter()
        .position(|h| h.split('[').next() == Some(name))
        .unwrap_or_else(|| panic!("no column {name} in {header:?}"));
    lines
        .map(|l| l.split(',').nth(k).expect("cell").parse().expect("number"))
        .collect()
}

/// A 3-axis mill whose X carriage has a scale error and a backlash, and whose head has a pitch
/// (an angular error a 3-axis machine cannot correct).
const MILL: &str = r#"
machine mill3 {
    task position
    units { length mm, error um, tilt urad }
    axis X prismatic along -x range 0 mm .. 500 mm
    axis Y prismatic along -y range 0 mm .. 400 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    tool chain {
        Z moving at (0, 0, 450) mm
        tool long at (0, 0, -150) mm
    }
    workpiece chain {
        Y fixed at (0, 200, 0) mm
        X fixed at (250, 0, 100) mm
        workpiece
    }
    errors {
        X.tx = linear(X) + backlash(X)
        Y.ty = linear(Y)
        Z.rx = const
    }
}
"#;

/// X.tx = 20 µm·(2X/500 mm − 1) + 3 µm·dir; Y.ty = −10 µm·(2Y/400 mm − 1); Z pitch 8 µrad.
const TRUTH: &str =
    "params {\n    X.tx = [20, 3] um\n    Y.ty = [-10] um\n    Z.rx = [8] urad\n}\n";

/// Writes the machine, simulates it without noise and fits it; returns the folder, the
/// machine and the fit.
fn fitted(name: &str) -> (PathBuf, PathBuf, PathBuf) {
    fitted_source(name, MILL)
}

fn fitted_source(name: &str, source: &str) -> (PathBuf, PathBuf, PathBuf) {
    let d = dir().join(name);
    std::fs::create_dir_all(&d).expect("dir");
    let machine = d.join("mill3.kin");
    let truth = d.join("truth.params");
    std::fs::write(&machine, source).expect("write");
    std::fs::write(&truth, TRUTH).expect("write");
    let sim = d.join("sim.csv");
    let fit = d.join("fit.json");
    let s = |p: &Path| p.to_str().expect("utf-8 path").to_string();
    ok(&kin(&[
        "simulate",
        &s(&machine),
        "--params",
        &s(&truth),
        "--sample",
        "200",
        "--components",
        "pose",
        "--noise",
        "0.05um",
        "--noise-tilt",
        "0.05urad",
        "-o",
        &s(&sim),
    ]));
    ok(&kin(&["fit", &s(&machine), &s(&sim), "-o", &s(&fit)]));
    (d, machine, fit)
}

#[test]
fn corrections_cancel_the_position_error_and_leave_the_pitch() {
    let (d, machine, fit) = fitted("csv");
    let out = d.join("comp.csv");
    let o = kin(&[
        "compensate",
        machine.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--grid",
        "X=0:500:100,Y=0:400:100,Z=-100,dir_X=-1",
        "-o",
        out.to_str().unwrap(),
    ]);
    ok(&o);
    let x = column(&out, "X");
    let y = column(&out, "Y");
    assert_eq!(x.len(), 6 * 5);
    let corr_x = column(&out, "corr_X");
    let corr_y = column(&out, "corr_Y");
    let rest_ex = column(&out, "rest_ex");
    let rest_erx = column(&out, "rest_erx");
    let u_ex = column(&out, "u_ex");
    for r in 0..x.len() {
        // The truth, by hand. The X carriage moves the table along −x, so a translation error
        // tx along its x leaves the joint at X − tx: the command must grow by tx (here moving
        // in −, dir −1). Y likewise, less the 8 µrad pitch of the head times its 150 mm tool
        // (1.2 µm along y). The fit knows these to its uncertainty.
        let tx = 20.0 * (2.0 * x[r] / 500.0 - 1.0) - 3.0;
        let ty = -10.0 * (2.0 * y[r] / 400.0 - 1.0);
        assert!(
            (corr_x[r] - tx).abs() < 5.0 * u_ex[r] + 0.01,
            "row {r}: corr_X {} for X.tx {tx}",
            corr_x[r]
        );
        assert!(
            (corr_y[r] - (ty - 1.2)).abs() < 0.05,
            "row {r}: corr_Y {} for Y.ty {ty}",
            corr_y[r]
        );
        assert!(rest_ex[r].abs() < 1e-6, "row {r}: {}", rest_ex[r]);
        // A pitch of the head: no axis of a 3-axis machine turns the tool.
        assert!((rest_erx[r] - 8.0).abs() < 0.05, "row {r}: {}", rest_erx[r]);
    }
    let stderr = text(&o.stderr);
    assert!(stderr.contains("30 poses"), "{stderr}");
    assert!(stderr.contains("cannot move"), "{stderr}");
}

/// A LinuxCNC compensation file as its documentation defines it: each line three numbers
/// separated by white space (nominal, forward, reverse); nominals ascending; ≤ 256 lines.
fn read_linuxcnc(path: &Path) -> Vec<[f64; 3]> {
    let s = std::fs::read_to_string(path).expect("comp file");
    let rows: Vec<[f64; 3]> = s
        .lines()
        .map(|line| {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(|t| {
                    t.parse()
                        .unwrap_or_else(|_| panic!("not a number: {line:?}"))
                })
                .collect();
            assert_eq!(v.len(), 3, "not a triplet: {line:?}");
            [v[0], v[1], v[2]]
        })
        .collect();
    assert!(
        !rows.is_empty() && rows.len() <= 256,
        "{} lines",
        rows.len()
    );
    assert!(
        rows.windows(2).all(|w| w[0][0] < w[1][0]),
        "nominals not ascending"
    );
    rows
}

#[test]
fn linuxcnc_tables_hold_the_axis_error_and_say_what_they_cannot() {
    let (d, machine, fit) = fitted("linuxcnc");
    let tables = d.join("tables");
    let o = kin(&[
        "compensate",
        machine.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--grid",
        "X=0:500:50,Y=0:400:100,Z=-100",
        "--table",
        "linuxcnc",
        "-o",
        tables.to_str().unwrap(),
    ]);
    ok(&o);
    let x = read_linuxcnc(&tables.join("X.comp"));
    assert_eq!(x.len(), 11);
    for [nominal, forward, reverse] in x {
        // Position reached = nominal − the carriage's own error X.tx (it moves along −x), mm.
        let scale = 20.0 * (2.0 * nominal / 500.0 - 1.0);
        let expect_fwd = nominal - (scale + 3.0) * 1e-3;
        let expect_rev = nominal - (scale - 3.0) * 1e-3;
        assert!(
            (forward - expect_fwd).abs() < 2e-5,
            "{nominal}: {forward} vs {expect_fwd}"
        );
        assert!(
            (reverse - expect_rev).abs() < 2e-5,
            "{nominal}: {reverse} vs {expect_rev}"
        );
    }
    let y = read_linuxcnc(&tables.join("Y.comp"));
    assert_eq!(y.len(), 5);
    assert!(!tables.join("Z.comp").exists(), "Z is held, not ranged");
    let note = std::fs::read_to_string(tables.join("kin-compensation.txt")).expect("note");
    assert!(note.contains("COMP_FILE_TYPE = 0"), "{note}");
    assert!(note.contains("cannot"), "{note}");
    assert!(note.contains("interpolation"), "{note}");
    assert!(text(&o.stderr).contains("with these tables"));
}

#[test]
fn bad_requests_are_refused_before_anything_is_written() {
    let (d, machine, fit) = fitted("refusals");
    let m = machine.to_str().unwrap();
    let f = fit.to_str().unwrap();
    let out = d.join("never.csv");
    let o = out.to_str().unwrap();
    // Outside an axis's range.
    let r = kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--grid",
        "X=0:600:100",
        "-o",
        o,
    ]);
    assert_eq!(r.status.code(), Some(2), "{}", text(&r.stderr));
    assert!(
        text(&r.stderr).contains("outside the range of axis X"),
        "{}",
        text(&r.stderr)
    );
    // An unknown name.
    let r = kin(&["compensate", m, "--fit", f, "--grid", "Q=1", "-o", o]);
    assert_eq!(r.status.code(), Some(2));
    assert!(
        text(&r.stderr).contains("`Q` is no axis"),
        "{}",
        text(&r.stderr)
    );
    // The output is an input.
    let r = kin(&["compensate", m, "--fit", f, "--grid", "X=0", "-o", f]);
    assert_eq!(r.status.code(), Some(2), "{}", text(&r.stderr));
    // A fit of another machine.
    let other = d.join("other.kin");
    std::fs::write(&other, MILL.replace("machine mill3", "machine other")).unwrap();
    let r = kin(&[
        "compensate",
        other.to_str().unwrap(),
        "--fit",
        f,
        "--grid",
        "X=0",
        "-o",
        o,
    ]);
    assert_eq!(r.status.code(), Some(1));
    assert!(
        text(&r.stderr).contains("is a fit of machine `mill3`"),
        "{}",
        text(&r.stderr)
    );
    // A measuring machine is corrected, not compensated.
    let cmm = d.join("cmm.kin");
    std::fs::write(&cmm, MILL.replace("task position", "task measure")).unwrap();
    let r = kin(&[
        "compensate",
        cmm.to_str().unwrap(),
        "--fit",
        f,
        "--grid",
        "X=0",
        "-o",
        o,
    ]);
    assert_eq!(r.status.code(), Some(1));
    assert!(
        text(&r.stderr).contains("kin correct"),
        "{}",
        text(&r.stderr)
    );
    // Too many entries for a LinuxCNC file.
    let t = d.join("tables");
    let r = kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--grid",
        "X=0:500:1",
        "--table",
        "linuxcnc",
        "-o",
        t.to_str().unwrap(),
    ]);
    assert_eq!(r.status.code(), Some(2));
    assert!(
        text(&r.stderr).contains("at most 256"),
        "{}",
        text(&r.stderr)
    );
    assert!(!out.exists());
    assert!(!t.join("X.comp").exists());
}

#[test]
fn help_shows_an_example() {
    let o = kin(&["compensate", "--help"]);
    ok(&o);
    let help = text(&o.stdout);
    assert!(
        help.contains("kin compensate mill.kin --fit fit.json --grid"),
        "{help}"
    );
    assert!(help.contains("linuxcnc"), "{help}");
}

#[test]
fn correct_takes_the_predicted_error_off_measured_coordinates() {
    let cmm = MILL.replace("task position", "task measure");
    let (d, machine, fit) = fitted_source("correct", &cmm);
    let s = |p: &Path| p.to_str().expect("utf-8 path").to_string();
    // Fresh points and their true error (exact, no noise) from the truth.
    let truth = d.join("truth.params");
    let points = d.join("points.csv");
    ok(&kin(&[
        "simulate",
        &s(&machine),
        "--params",
        &s(&truth),
        "--sample",
        "40",
        "--seed",
        "9",
        "-o",
        &s(&points),
    ]));
    let out = d.join("corrected.csv");
    let o = kin(&[
        "correct",
        &s(&machine),
        "--fit",
        &s(&fit),
        &s(&points),
        "-o",
        &s(&out),
    ]);
    ok(&o);
    for (axis, k) in [("x", "ex"), ("y", "ey"), ("z", "ez")] {
        let measured = column(&out, axis);
        let corrected = column(&out, &format!("{axis}_corrected"));
        let u = column(&out, &format!("u_{axis}"));
        let true_error = column(&points, k);
        assert_eq!(corrected.len(), 40);
        for r in 0..40 {
            // mm; the error in µm. The true coordinate is measured − true error.
            let truth = measured[r] - true_error[r] * 1e-3;
            let miss = (corrected[r] - truth).abs() * 1e3;
            assert!(
                miss <= 5.0 * u[r] + 1e-4,
                "{axis} row {r}: off by {miss} um, u = {} um",
                u[r]
            );
            assert!(true_error[r].abs() > 1e-3 || axis == "z");
        }
    }
    // A positioning machine is compensated, not corrected.
    let (_, mill, mill_fit) = fitted("correct-refused");
    let r = kin(&[
        "correct",
        &s(&mill),
        "--fit",
        &s(&mill_fit),
        &s(&points),
        "-o",
        &s(&d.join("no.csv")),
    ]);
    assert_eq!(r.status.code(), Some(1));
    assert!(
        text(&r.stderr).contains("kin compensate"),
        "{}",
        text(&r.stderr)
    );
}

/// `kin report --compensation`: the error along each axis before and after compensation, and
/// what stays (the head's pitch, which no axis of a 3-axis machine turns).
#[test]
fn the_report_shows_the_error_before_and_after_compensation() {
    let (d, machine, fit) = fitted("report");
    let page = d.join("report.html");
    ok(&kin(&[
        "report",
        machine.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--compensation",
        "-o",
        page.to_str().unwrap(),
        "--color",
        "never",
    ]));
    let html = std::fs::read_to_string(&page).expect("report written");
    let start = html
        .find("<section id=\"compensation\">")
        .expect("the section");
    let section = &html[start..];
    let section = &section[..section.find("</section>").expect("closed")];
    // Three axes, a position and an orientation plot each.
    assert_eq!(section.matches("<svg").count(), 6, "{section}");
    assert_eq!(section.matches("</svg>").count(), 6);
    for axis in ["X", "Y", "Z"] {
        assert!(section.contains(&format!("position error along {axis}")));
    }
    // The table: per swept axis, max position before/after (µm), orientation before/after
    // (µrad), rank.
    let rows: Vec<Vec<String>> = section
        .split("<tr><td class=\"l\">")
        .skip(1)
        .map(|r| {
            r.split("</td><td>")
                .map(|c| c.replace("</td></tr>", "").trim().to_string())
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), 3, "{section}");
    assert!(
        rows.iter()
            .any(|r| r[1].parse::<f64>().is_ok_and(|v| v > 10.0)),
        "tens of µm along some axis: {rows:?}"
    );
    let number = |c: &str| -> f64 {
        c.split('\n')
            .next()
            .unwrap_or(c)
            .replace('−', "-")
            .trim()
            .parse()
            .unwrap_or_else(|_| panic!("a number: {c:?}"))
    };
    for r in &rows {
        let (before, after) = (number(&r[1]), number(&r[2]));
        let (tilt_before, tilt_after) = (number(&r[3]), number(&r[4]));
        assert!(before > 1.0, "the errors are µm: {r:?}");
        assert!(after < 0.01, "the position is corrected: {r:?}");
        // The pitch of the head (8 µrad) stays: no correction turns the tool.
        assert!(
            tilt_after > 7.0 && (tilt_after - tilt_before).abs() < 0.5,
            "{r:?}"
        );
        assert_eq!(number(&r[5]), 3.0, "{r:?}");
    }
    // A measuring machine has no compensation: the section says so, the page is still written.
    let cmm = d.join("cmm.kin");
    std::fs::write(
        &cmm,
        std::fs::read_to_string(&machine).expect("model").replacen(
            "task position",
            "task measure",
            1,
        ),
    )
    .expect("write");
    let o = kin(&[
        "report",
        cmm.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--compensation",
        "-o",
        d.join("cmm.html").to_str().unwrap(),
    ]);
    // The same coefficients, another text: a warning (W0802), and the page says why there is
    // no compensation.
    ok(&o);
    let html = std::fs::read_to_string(d.join("cmm.html")).expect("report written");
    let start = html.find("<section id=\"compensation\">").expect("the section");
    let section = &html[start..];
    let section = &section[..section.find("</section>").expect("closed")];
    assert!(
        section.contains("No compensation") && section.contains("measuring machine"),
        "{section}"
    );
    assert_eq!(section.matches("<svg").count(), 0);
}
