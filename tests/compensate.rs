//! End-to-end runs of `kin compensate` and `kin correct`: a machine with known errors is
//! simulated and fitted by the binary, then compensated; the LinuxCNC tables are read back
//! by a parser written from LinuxCNC's documentation of `COMP_FILE` (lines of three numbers:
//! nominal, position reached moving in +, position reached moving in −; nominals ascending;
//! at most 256 lines).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;
use common::{browser, run_browser};

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

/// The 5-axis mill of the table tests — A tilting, C turning the table, the tool on Z — with
/// the error lines given.
fn mill5(errors: &[&str]) -> String {
    let mut source = String::from(
        r#"
machine mill5 {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis X prismatic along -x range 0 mm .. 500 mm
    axis Y prismatic along -y range 0 mm .. 400 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    axis A revolute about x range -90 deg .. 90 deg
    axis C revolute about z continuous
    tool chain {
        Z moving at (0, 0, 450) mm
        tool long at (0, 0, -150) mm
    }
    workpiece chain {
        Y fixed at (0, 200, 0) mm
        X fixed at (250, 0, 100) mm
        A fixed at (0, 0, 50) mm
        C fixed at (0, 0, 30) mm
        workpiece
    }
    errors {
"#,
    );
    for line in errors {
        source.push_str(&format!("        {line}\n"));
    }
    source.push_str("    }\n}\n");
    source
}

/// Writes the machine, simulates it without noise and fits it; returns the folder, the
/// machine and the fit.
fn fitted(name: &str) -> (PathBuf, PathBuf, PathBuf) {
    fitted_source(name, MILL)
}

fn fitted_source(name: &str, source: &str) -> (PathBuf, PathBuf, PathBuf) {
    fitted_truth(name, source, TRUTH)
}

fn fitted_truth(name: &str, source: &str, truth_text: &str) -> (PathBuf, PathBuf, PathBuf) {
    let d = dir().join(name);
    std::fs::create_dir_all(&d).expect("dir");
    let machine = d.join("mill3.kin");
    let truth = d.join("truth.params");
    std::fs::write(&machine, source).expect("write");
    std::fs::write(&truth, truth_text).expect("write");
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
/// `kin-leftover.csv` of a table set: a row per grid pose (`poses` of them); `before` is the
/// fitted model's predicted position error there (evaluated here by the embedding API), `full`
/// never exceeds `tables`, and the largest `tables` is the note's figure.
fn leftover_agrees_with_the_model(
    tables: &Path,
    machine: &Path,
    fit: &Path,
    note: &str,
    poses: usize,
) {
    let text = std::fs::read_to_string(tables.join("kin-leftover.csv")).expect("leftover");
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|c| c.parse().expect("number")).collect())
        .collect();
    assert_eq!(rows.len(), poses, "{text}");
    let col = |name: &str| {
        header
            .iter()
            .position(|h| h.starts_with(&format!("{name}[")))
            .unwrap_or_else(|| panic!("no {name} in {header:?}"))
    };
    let (before, tables_col, full) = (col("before"), col("tables"), col("full"));
    let source = std::fs::read_to_string(machine).expect("machine");
    let params = std::fs::read_to_string(fit.with_extension("params")).expect("FIT.params");
    let model = kin_model::Model::compile(&source)
        .expect("compiles")
        .with_params(&params)
        .expect("binds");
    let m = model.machine();
    let mut worst_tables = 0.0f64;
    for row in &rows {
        let mut s = model.state();
        for (a, axis) in m.axes.iter().enumerate() {
            let scale = match axis.kind {
                kin_compiler::ir::JointKind::Prismatic => 1e-3,
                kin_compiler::ir::JointKind::Revolute => 1f64.to_radians(),
            };
            s.q[a] = row[col(&axis.name)] * scale;
            s.dirs[a] = 1.0;
        }
        let mut e = [0.0; 6];
        model.eval(&s.get(), model.beta(), &mut e).expect("eval");
        let predicted = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt() * 1e6;
        assert!(
            (row[before] - predicted).abs() < 1e-4,
            "{row:?}: before {} um, the model predicts {predicted} um",
            row[before]
        );
        assert!(row[full] <= row[tables_col] + 1e-6, "{row:?}");
        worst_tables = worst_tables.max(row[tables_col]);
    }
    assert!(
        note.contains(&format!("{worst_tables:.4} um with these tables")),
        "largest {worst_tables:.4}: {note}"
    );
}

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
    leftover_agrees_with_the_model(&tables, &machine, &fit, &note, 11 * 5);
    // The set is replaced as one: a new set over X alone removes the earlier Y.comp (a
    // controller would keep loading it) and keeps the controller's own files.
    std::fs::write(tables.join("mill.ini"), "[JOINT_0]\nCOMP_FILE = X.comp\n").expect("ini");
    let o = kin(&[
        "compensate",
        machine.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--grid",
        "X=0:500:50,Y=200,Z=-100",
        "--table",
        "linuxcnc",
        "-o",
        tables.to_str().unwrap(),
    ]);
    ok(&o);
    assert!(!tables.join("Y.comp").exists(), "a stale Y.comp stays");
    assert!(
        text(&o.stderr).contains("Removed with the earlier set"),
        "{}",
        text(&o.stderr)
    );
    assert_eq!(
        std::fs::read_to_string(tables.join("mill.ini")).expect("ini kept"),
        "[JOINT_0]\nCOMP_FILE = X.comp\n"
    );
    assert_eq!(read_linuxcnc(&tables.join("X.comp")).len(), 11);
    let note = std::fs::read_to_string(tables.join("kin-compensation.txt")).expect("note");
    assert!(
        note.contains("Files of this set: X.comp, kin-leftover.csv, kin-compensation.txt."),
        "{note}"
    );
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

/// The truth of the fixture, by hand (see `corrections_cancel_the_position_error_and_leave_the_pitch`):
/// the correction of X moving in `dir`, and of Y (its straightness less the head's pitch seen
/// through the 150 mm tool), in µm.
fn truth_dx(x: f64, dir: f64) -> f64 {
    20.0 * (2.0 * x / 500.0 - 1.0) + 3.0 * dir
}
fn truth_dy(y: f64) -> f64 {
    -10.0 * (2.0 * y / 400.0 - 1.0) - 1.2
}

/// A SINUMERIK part program as Siemens' K3 manual defines it: a first line `%_N_NAME_INI`,
/// `;` comments, `CHANDATA(1)`, then one assignment `$VARIABLE[indices]=value` per line, the
/// last line `M17`. Returns the name and the assignments (variable, indices, value text).
fn read_sinumerik(path: &Path) -> (String, Vec<(String, Vec<String>, String)>) {
    let s = std::fs::read_to_string(path).expect("part program");
    let mut lines = s
        .lines()
        .map(|l| l.split(';').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty());
    let name = lines.next().expect("name line");
    assert!(name.starts_with("%_N_") && name.ends_with("_INI"), "{name}");
    assert_eq!(lines.next(), Some("CHANDATA(1)"));
    let mut out = Vec::new();
    let mut ended = false;
    for line in lines {
        assert!(!ended, "after M17: {line}");
        if line == "M17" {
            ended = true;
            continue;
        }
        let (lhs, value) = line.split_once('=').unwrap_or_else(|| panic!("{line}"));
        let (var, rest) = lhs.split_once('[').unwrap_or_else(|| panic!("{line}"));
        assert!(var.starts_with('$'), "{line}");
        let indices = rest
            .strip_suffix(']')
            .unwrap_or_else(|| panic!("{line}"))
            .split(',')
            .map(|t| t.trim().to_string())
            .collect();
        out.push((var.to_string(), indices, value.trim().to_string()));
    }
    assert!(ended, "no M17");
    (name.to_string(), out)
}

fn number(text: &str) -> f64 {
    text.parse()
        .unwrap_or_else(|_| panic!("not a number: {text:?}"))
}

#[test]
fn sinumerik_programs_hold_leadscrew_backlash_and_agree_with_the_model() {
    let (d, machine, fit) = fitted("sinumerik");
    let tables = d.join("sinumerik");
    let o = kin(&[
        "compensate",
        machine.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--grid",
        "X=0:500:50,Y=0:400:100,Z=-100",
        "--table",
        "sinumerik",
        "-o",
        tables.to_str().unwrap(),
    ]);
    ok(&o);
    // Leadscrew tables: Y only (X has backlash, so it goes to direction-dependent CEC tables).
    let (name, lec) = read_sinumerik(&tables.join("AX_EEC.INI"));
    assert_eq!(name, "%_N_AX_EEC_INI");
    let get = |var: &str, idx: &[&str]| -> f64 {
        let hit = lec
            .iter()
            .find(|(v, i, _)| v == var && i.iter().map(String::as_str).eq(idx.iter().copied()))
            .unwrap_or_else(|| panic!("no {var}{idx:?}"));
        number(&hit.2)
    };
    assert!(
        lec.iter()
            .all(|(_, i, _)| i.last().map(String::as_str) == Some("Y")),
        "{lec:?}"
    );
    let (min, step, max) = (
        get("$AA_ENC_COMP_MIN", &["0", "Y"]),
        get("$AA_ENC_COMP_STEP", &["0", "Y"]),
        get("$AA_ENC_COMP_MAX", &["0", "Y"]),
    );
    assert_eq!((min, step, max), (0.0, 100.0, 400.0));
    assert_eq!(get("$AA_ENC_COMP_IS_MODULO", &["0", "Y"]), 0.0);
    for n in 0..5 {
        let y = min + step * n as f64;
        // The value is the axis's error: a positive one moves the axis the negative way, so it
        // is minus the correction, in mm.
        let v = get("$AA_ENC_COMP", &["0", &n.to_string(), "Y"]);
        let expect = -truth_dy(y) * 1e-3;
        assert!((v - expect).abs() < 5e-5, "Y={y}: {v} vs {expect}");
    }
    // Sag / cross-error tables: X onto itself, one per direction; no cross table (no error of
    // one axis here depends on another's position).
    let (name, cec) = read_sinumerik(&tables.join("NC_CEC.INI"));
    assert_eq!(name, "%_N_NC_CEC_INI");
    let table = |var: &str, t: usize| -> String {
        cec.iter()
            .find(|(v, i, _)| v == var && i.len() == 1 && i[0] == t.to_string())
            .unwrap_or_else(|| panic!("no {var}[{t}]"))
            .2
            .clone()
    };
    let count = cec
        .iter()
        .filter(|(v, _, _)| v == "$AN_CEC_INPUT_AXIS")
        .count();
    assert_eq!(count, 2, "{cec:?}");
    for t in 0..2 {
        assert_eq!(table("$AN_CEC_INPUT_AXIS", t), "(X)");
        assert_eq!(table("$AN_CEC_OUTPUT_AXIS", t), "(X)");
        let dir = number(&table("$AN_CEC_DIRECTION", t));
        assert!(dir == 1.0 || dir == -1.0);
        let (min, step) = (
            number(&table("$AN_CEC_MIN", t)),
            number(&table("$AN_CEC_STEP", t)),
        );
        assert_eq!((min, step), (0.0, 50.0));
        assert_eq!(number(&table("$AN_CEC_MAX", t)), 500.0);
        let values: Vec<f64> = cec
            .iter()
            .filter(|(v, i, _)| v == "$AN_CEC" && i[0] == t.to_string())
            .map(|(_, _, value)| number(value))
            .collect();
        assert_eq!(values.len(), 11);
        for (n, v) in values.iter().enumerate() {
            let x = min + step * n as f64;
            let expect = -truth_dx(x, dir) * 1e-3;
            assert!(
                (v - expect).abs() < 2e-5,
                "X={x} dir {dir}: {v} vs {expect}"
            );
        }
    }
    let note = std::fs::read_to_string(tables.join("kin-compensation.txt")).expect("note");
    assert!(note.contains("backlash"), "{note}");
    assert!(note.contains("interpolation"), "{note}");
    assert!(text(&o.stderr).contains("with these tables"));
}

/// The SINUMERIK tables of `dir` evaluated as K3 describes the controller doing it: for a
/// machine axis, its leadscrew value plus every cross table whose output it is and whose
/// direction matches `dir` (0 both, ±1 one), each linearly interpolated at its input axis's
/// position (held at the ends). `positions` gives each axis's position by name, in mm.
fn sinumerik_total(
    lec: &[(String, Vec<String>, String)],
    cec: &[(String, Vec<String>, String)],
    axis: &str,
    dir: f64,
    positions: &dyn Fn(&str) -> f64,
) -> f64 {
    let interpolate = |min: f64, step: f64, values: &[f64], at: f64| -> f64 {
        let u = ((at - min) / step).clamp(0.0, (values.len() - 1) as f64);
        let k = (u.floor() as usize).min(values.len().saturating_sub(2));
        let t = u - k as f64;
        values[k] + t * (values.get(k + 1).copied().unwrap_or(values[k]) - values[k])
    };
    let mut total = 0.0;
    let lec_values: Vec<f64> = lec
        .iter()
        .filter(|(v, i, _)| v == "$AA_ENC_COMP" && i.len() == 3 && i[2] == axis)
        .map(|(_, _, x)| number(x))
        .collect();
    if !lec_values.is_empty() {
        let scalar = |var: &str| {
            number(
                &lec.iter()
                    .find(|(v, i, _)| v == var && i.len() == 2 && i[1] == axis)
                    .expect("table parameter")
                    .2,
            )
        };
        total += interpolate(
            scalar("$AA_ENC_COMP_MIN"),
            scalar("$AA_ENC_COMP_STEP"),
            &lec_values,
            positions(axis),
        );
    }
    let tables = cec
        .iter()
        .filter(|(v, _, _)| v == "$AN_CEC_INPUT_AXIS")
        .count();
    for t in 0..tables {
        let scalar = |var: &str| -> String {
            cec.iter()
                .find(|(v, i, _)| v == var && i.len() == 1 && i[0] == t.to_string())
                .expect("table parameter")
                .2
                .clone()
        };
        if scalar("$AN_CEC_OUTPUT_AXIS") != format!("({axis})") {
            continue;
        }
        let direction = number(&scalar("$AN_CEC_DIRECTION"));
        if direction != 0.0 && direction != dir {
            continue;
        }
        let input = scalar("$AN_CEC_INPUT_AXIS");
        let input = input.trim_matches(|c| c == '(' || c == ')');
        let values: Vec<f64> = cec
            .iter()
            .filter(|(v, i, _)| v == "$AN_CEC" && i[0] == t.to_string())
            .map(|(_, _, x)| number(x))
            .collect();
        total += interpolate(
            number(&scalar("$AN_CEC_MIN")),
            number(&scalar("$AN_CEC_STEP")),
            &values,
            positions(input),
        );
    }
    total
}

#[test]
fn sinumerik_cross_tables_hold_a_squareness_with_the_leadscrew_tables() {
    // The fixture plus an X–Y squareness: a constant yaw of the X table's frame, which turns
    // X's motion and the part against Y's motion (a yaw of Y's own fixed frame would turn the
    // whole workpiece side together: a constant error, no squareness).
    let source = MILL.replace("Z.rx = const", "Z.rx = const\n        X.rz = const");
    let truth = TRUTH.replace("}", "    X.rz = [40] urad\n}");
    let (d, machine, fit) = fitted_truth("sinumerik-cross", &source, &truth);
    let (m, f) = (machine.to_str().unwrap(), fit.to_str().unwrap());
    let grid = "X=0:500:100,Y=0:400:100,Z=-100";
    let tables = d.join("tables");
    let o = kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--grid",
        grid,
        "--table",
        "sinumerik",
        "-o",
        tables.to_str().unwrap(),
    ]);
    ok(&o);
    let (_, lec) = read_sinumerik(&tables.join("AX_EEC.INI"));
    let (_, cec) = read_sinumerik(&tables.join("NC_CEC.INI"));
    let crossing = cec
        .iter()
        .filter(|(v, _, value)| v == "$AN_CEC_INPUT_AXIS" && value == "(Y)")
        .count();
    assert!(crossing >= 1, "no table along Y: {cec:?}");
    // The sign, which Siemens' manual states for leadscrew tables only, is made explicit with a
    // check on the machine at the largest value: the output axis must move against it.
    let largest_cec = cec
        .iter()
        .filter(|(v, _, _)| v == "$AN_CEC")
        .map(|(_, _, value)| number(value))
        .max_by(|a, b| a.abs().total_cmp(&b.abs()))
        .expect("CEC values");
    let program = std::fs::read_to_string(tables.join("NC_CEC.INI")).expect("NC_CEC.INI");
    let check = program
        .lines()
        .find(|l| l.starts_with("; Sign check"))
        .unwrap_or_else(|| panic!("no sign check in\n{program}"));
    let shown = |v: f64| format!("{}", (v * 1e6).round() / 1e6);
    assert!(
        check.contains(&format!("must change by {} mm", shown(-largest_cec)))
            && check.contains(&format!("If it changes by {} mm", shown(largest_cec))),
        "{check} (largest value {largest_cec})"
    );
    // The full compensation of every grid pose, by the CSV path.
    let csv = d.join("full.csv");
    ok(&kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--grid",
        grid,
        "-o",
        csv.to_str().unwrap(),
    ]));
    let (x, y) = (column(&csv, "X"), column(&csv, "Y"));
    let (corr_x, corr_y) = (column(&csv, "corr_X"), column(&csv, "corr_Y"));
    let mut largest = 0.0_f64;
    for r in 0..x.len() {
        let at = |name: &str| match name {
            "X" => x[r],
            "Y" => y[r],
            _ => -100.0,
        };
        // Table values are the axes' errors in mm: minus the corrections (µm).
        for (axis, corr) in [("X", corr_x[r]), ("Y", corr_y[r])] {
            let total = sinumerik_total(&lec, &cec, axis, 1.0, &at);
            let miss = (total + corr * 1e-3).abs();
            largest = largest.max(corr.abs());
            assert!(
                miss < 1e-5,
                "{axis} at X={} Y={}: tables {total} mm, full −{corr} um",
                x[r],
                y[r]
            );
        }
    }
    // The squareness makes the corrections of X vary with Y by about 40 µrad × 400 mm.
    assert!(largest > 10.0, "{largest}");
}

/// An ISG compensation list as ISG documents it: `name value` lines, `#` comment lines,
/// `/* … */` comments, `End` last; here the `kw.ssfk` leadscrew entries, integers.
fn read_isg_list(path: &Path) -> std::collections::HashMap<String, String> {
    let s = std::fs::read_to_string(path).expect("list");
    let mut map = std::collections::HashMap::new();
    let mut ended = false;
    for raw in s.lines() {
        let line = match raw.find("/*") {
            Some(k) => &raw[..k],
            None => raw,
        }
        .trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        assert!(!ended, "after End: {line}");
        if line == "End" {
            ended = true;
            continue;
        }
        let mut it = line.split_whitespace();
        let (Some(name), Some(value), None) = (it.next(), it.next(), it.next()) else {
            panic!("not `name value`: {line:?}");
        };
        assert!(
            map.insert(name.to_string(), value.to_string()).is_none(),
            "{name} twice"
        );
    }
    map
}

#[test]
fn isg_lists_hold_both_directions_in_tenths_of_a_micrometre() {
    let (d, machine, fit) = fitted("isg");
    let tables = d.join("isg");
    let o = kin(&[
        "compensate",
        machine.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--grid",
        "X=0:500:50,Y=0:400:100,Z=-100",
        "--table",
        "isg-lsec",
        "-o",
        tables.to_str().unwrap(),
    ]);
    ok(&o);
    let list = read_isg_list(&tables.join("X.lis"));
    let int = |name: &str| -> i64 {
        list.get(name)
            .unwrap_or_else(|| panic!("no {name}"))
            .parse()
            .unwrap_or_else(|_| panic!("{name} is not an integer"))
    };
    assert_eq!(
        list.get("kopf.log_achs_name").map(String::as_str),
        Some("X")
    );
    assert_eq!(int("kw.ssfk.unit"), 1);
    assert_eq!(int("kw.ssfk.bilateral"), 1);
    assert_eq!(int("kw.ssfk.interval"), 0);
    let n = int("kw.ssfk.kw_nr_max");
    assert_eq!(n, 11);
    assert_eq!(int("kw.ssfk.kw_startpos"), int("kw.ssfk.table[0].setpoint"));
    for i in 0..n {
        let setpoint = int(&format!("kw.ssfk.table[{i}].setpoint"));
        let x = setpoint as f64 * 1e-4; // 0.1 µm → mm
        assert!((x - 50.0 * i as f64).abs() < 1e-9, "{x}");
        // actual − setpoint, in 0.1 µm: minus the correction.
        for (entry, dir) in [("pos", 1.0), ("neg", -1.0)] {
            let v = int(&format!("kw.ssfk.table[{i}].{entry}"));
            let expect = -truth_dx(x, dir) * 10.0;
            assert!(
                (v as f64 - expect).abs() <= 1.0,
                "X={x} {entry}: {v} vs {expect}"
            );
        }
    }
    assert!(tables.join("Y.lis").exists());
    assert!(!tables.join("Z.lis").exists());
}

/// ISG CSV as ISG documents it: `//` comment lines, a header of argument and parameter names,
/// records of white-space separated numbers. Returns the header and the records.
fn read_isg_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let s = std::fs::read_to_string(path).expect("csv");
    let mut lines = s
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("//"));
    let header: Vec<String> = lines
        .next()
        .expect("header")
        .split_whitespace()
        .map(String::from)
        .collect();
    let records: Vec<Vec<f64>> = lines
        .map(|l| {
            assert!(!l.starts_with('#'), "a second block: {l}");
            let r: Vec<f64> = l.split_whitespace().map(number).collect();
            assert_eq!(r.len(), header.len(), "{l}");
            r
        })
        .collect();
    (header, records)
}

#[test]
fn volcomp_files_hold_the_iso_component_errors_of_each_axis() {
    let (d, machine, fit) = fitted("volcomp");
    let tables = d.join("volcomp");
    let o = kin(&[
        "compensate",
        machine.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--grid",
        "X=0:500:50,Y=0:400:100,Z=-300:0:100",
        "--table",
        "volcomp",
        "-o",
        tables.to_str().unwrap(),
    ]);
    ok(&o);
    let (header, x) = read_isg_csv(&tables.join("X.csv"));
    assert_eq!(header, ["X", "EXX", "EYX", "EZX", "EAX", "EBX", "ECX"]);
    assert_eq!(x.len(), 11);
    for r in &x {
        // X moves the workpiece along −x: its carriage's error X.tx (mean of both directions)
        // is seen by the tool relative to the workpiece with the opposite sign, in mm.
        let expect = -20.0 * (2.0 * r[0] / 500.0 - 1.0) * 1e-3;
        assert!(
            (r[1] - expect).abs() < 2e-5,
            "X={}: {} vs {expect}",
            r[0],
            r[1]
        );
        for v in &r[2..] {
            assert!(v.abs() < 1e-9, "{r:?}");
        }
    }
    let (header, y) = read_isg_csv(&tables.join("Y.csv"));
    assert_eq!(header[1], "EXY");
    for r in &y {
        let expect = 10.0 * (2.0 * r[0] / 400.0 - 1.0) * 1e-3;
        assert!(
            (r[2] - expect).abs() < 2e-5,
            "Y={}: {} vs {expect}",
            r[0],
            r[2]
        );
    }
    let (_, z) = read_isg_csv(&tables.join("Z.csv"));
    assert_eq!(z.len(), 4);
    for r in &z {
        // The head's pitch: 8 µrad about x, on the tool side, in rad.
        assert!((r[4] - 8e-6).abs() < 5e-8, "{r:?}");
    }
    let note = std::fs::read_to_string(tables.join("kin-compensation.txt")).expect("note");
    assert!(note.contains("workpiece_axes 0"), "{note}");
    assert!(note.contains("backlash"), "{note}");
}

#[test]
fn formats_refuse_what_they_cannot_state() {
    let (d, machine, fit) = fitted("format-refusals");
    let m = machine.to_str().unwrap();
    let f = fit.to_str().unwrap();
    let run = |grid: &str, format: &str, out: &Path| {
        kin(&[
            "compensate",
            m,
            "--fit",
            f,
            "--grid",
            grid,
            "--table",
            format,
            "-o",
            out.to_str().unwrap(),
        ])
    };
    // SINUMERIK tables are equidistant: 0, 30, …, 480, 500 is not.
    let out = d.join("s");
    let r = run("X=0:500:30", "sinumerik", &out);
    assert_eq!(r.status.code(), Some(2), "{}", text(&r.stderr));
    assert!(
        text(&r.stderr).contains("equidistant"),
        "{}",
        text(&r.stderr)
    );
    assert!(!out.join("NC_CEC.INI").exists() && !out.join("AX_EEC.INI").exists());
    // ISG lists state positions in whole 0.1 µm.
    let out = d.join("i");
    let r = run("X=0:500:33.33333333", "isg-lsec", &out);
    assert_eq!(r.status.code(), Some(2), "{}", text(&r.stderr));
    assert!(text(&r.stderr).contains("0.1 um"), "{}", text(&r.stderr));
    assert!(!out.join("X.lis").exists());
    // VolComp names axes X Y Z A B C: a fourth axis U (a quill along x) has no ISO letter.
    let with_u = MILL
        .replace(
            "axis Z prismatic",
            "axis U prismatic along x range 0 mm .. 100 mm\n    axis Z prismatic",
        )
        .replace("tool chain {", "tool chain {\n        U moving");
    let (_, machine_u, fit_u) = fitted_source("format-refusals-u", &with_u);
    let out = d.join("v");
    let r = kin(&[
        "compensate",
        machine_u.to_str().unwrap(),
        "--fit",
        fit_u.to_str().unwrap(),
        "--grid",
        "X=0:500:50,U=0:100:50",
        "--table",
        "volcomp",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(r.status.code(), Some(1), "{}", text(&r.stderr));
    assert!(
        text(&r.stderr).contains("ISO 230-1 letters"),
        "{}",
        text(&r.stderr)
    );
    assert!(!out.join("X.csv").exists());
    assert!(!out.join("U.csv").exists());
}

#[test]
fn a_table_set_that_cannot_be_written_leaves_the_old_set_whole() {
    let (d, machine, fit) = fitted("unwritable");
    let out = d.join("volcomp");
    std::fs::create_dir_all(out.join("Y.csv")).unwrap();
    std::fs::write(out.join("X.csv"), "old\n").unwrap();
    let o = kin(&[
        "compensate",
        machine.to_str().unwrap(),
        "--fit",
        fit.to_str().unwrap(),
        "--grid",
        "X=0:500:100,Y=0:400:100,Z=-100",
        "--table",
        "volcomp",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(
        text(&o.stderr).contains("it is a folder"),
        "{}",
        text(&o.stderr)
    );
    assert_eq!(std::fs::read_to_string(out.join("X.csv")).unwrap(), "old\n");
    assert!(!out.join("kin-compensation.txt").exists());
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
    for format in ["linuxcnc", "sinumerik", "isg-lsec", "volcomp"] {
        assert!(help.contains(format), "{format}: {help}");
    }
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
    let start = html
        .find("<section id=\"compensation\">")
        .expect("the section");
    let section = &html[start..];
    let section = &section[..section.find("</section>").expect("closed")];
    assert!(
        section.contains("No compensation") && section.contains("measuring machine"),
        "{section}"
    );
    assert_eq!(section.matches("<svg").count(), 0);
}

/// The script the browser test adds to a copy of the report: once the page has loaded and laid
/// out, it measures the compensation section as drawn (its box, each plot's box, the boxes of
/// the before/after lines, told apart by their colours) and reads the table as rendered text,
/// into a `<pre id="kin-probe">` that `--dump-dom` prints.
const PROBE: &str = r#"<script>
addEventListener('load', () => {
  const sec = document.getElementById('compensation');
  const box = (e) => { const r = e.getBoundingClientRect(); return [r.width, r.height]; };
  const union = (els) => {
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity, n = 0;
    for (const e of els) {
      const b = e.getBBox();
      x0 = Math.min(x0, b.x); x1 = Math.max(x1, b.x + b.width);
      y0 = Math.min(y0, b.y); y1 = Math.max(y1, b.y + b.height);
      n += e.points.numberOfItems;
    }
    return { x0, x1, y0, y1, points: n, parts: els.length };
  };
  const line = (svg, colour) => union([...svg.querySelectorAll('polyline')]
    .filter(p => p.getAttribute('stroke').toUpperCase() === colour));
  const plots = [...sec.querySelectorAll('svg')].map(svg => ({
    box: box(svg),
    title: svg.textContent.trim().split('\n')[0],
    axis: line(svg, '#969BA5'),
    before: line(svg, '#E69F00'),
    after: line(svg, '#0072B2'),
  }));
  const rows = [...sec.querySelectorAll('table tr')].slice(1)
    .map(tr => [...tr.cells].map(c => c.innerText));
  const pre = document.createElement('pre');
  pre.id = 'kin-probe';
  pre.textContent = JSON.stringify({ section: box(sec), display: getComputedStyle(sec).display, plots, rows });
  document.body.appendChild(pre);
});
</script>"#;

/// The compensation section in a real browser (headless Chromium, as `tests/report.rs` uses
/// it): it is laid out and visible, each of its plots is drawn with a before line that spans
/// the swept range through every point and a dashed after line, and the numbers its table shows
/// are those `kin compensate` writes for the same sweep (each axis over its range in 40 steps,
/// the others at the middle of theirs, directions positive).
#[test]
fn the_compensation_section_renders_in_a_browser_and_agrees_with_kin_compensate() {
    let Some(chromium) = browser() else {
        println!("browser check skipped: no chromium at /usr/bin/chromium or on PATH");
        return;
    };
    let (d, machine, fit) = fitted("browser");
    let s = |p: &Path| p.to_str().expect("utf-8 path").to_string();
    let page = d.join("report.html");
    ok(&kin(&[
        "report",
        &s(&machine),
        "--fit",
        &s(&fit),
        "--compensation",
        "-o",
        &s(&page),
    ]));
    let html = std::fs::read_to_string(&page).expect("report");
    let probed = d.join("probed.html");
    std::fs::write(
        &probed,
        html.replacen("</body>", &format!("{PROBE}</body>"), 1),
    )
    .expect("copy");
    let url = format!("file://{}", probed.canonicalize().expect("path").display());
    let profile = d.join("chromium-profile");
    let out = run_browser(
        &chromium,
        &[
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            &format!("--user-data-dir={}", profile.display()),
            "--window-size=1280,4000",
            "--virtual-time-budget=10000",
            "--dump-dom",
            &url,
        ],
    );
    let dom = text(&out);
    let start = dom.find("<pre id=\"kin-probe\">").expect("the probe ran") + 20;
    let json = &dom[start..start + dom[start..].find("</pre>").expect("closed")];
    let json = json
        .replace("&amp;", "&")
        .replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"");
    let probe: serde_json::Value = serde_json::from_str(&json).expect("probe JSON");
    let num = |v: &serde_json::Value| v.as_f64().expect("a number");
    // Laid out and visible.
    assert_ne!(probe["display"], "none");
    assert!(
        num(&probe["section"][0]) > 800.0 && num(&probe["section"][1]) > 600.0,
        "{probe}"
    );
    // Three axes, a position and an orientation plot each, drawn (the page's grid scales the
    // 420 × 290 charts to its columns, keeping their shape).
    let plots = probe["plots"].as_array().expect("plots");
    assert_eq!(plots.len(), 6, "{probe}");
    for p in plots {
        let (w, h) = (num(&p["box"][0]), num(&p["box"][1]));
        assert!(w >= 300.0 && (w / h - 420.0 / 290.0).abs() < 0.02, "{p}");
        let (x0, x1) = (num(&p["axis"]["x0"]), num(&p["axis"]["x1"]));
        // The before line: one polyline through all 41 points of the sweep, from one end of
        // the x axis to the other (the data fill the axis, less the chart's margins).
        assert_eq!(num(&p["before"]["points"]), 41.0, "{p}");
        let span = num(&p["before"]["x1"]) - num(&p["before"]["x0"]);
        assert!(span > 0.9 * (x1 - x0), "{p}");
        // The after line: dashed, so many pieces, over the same span.
        assert!(num(&p["after"]["parts"]) > 10.0, "{p}");
        assert!(
            num(&p["after"]["x1"]) - num(&p["after"]["x0"]) > 0.9 * span,
            "{p}"
        );
    }
    // Along X the position error varies (the scale error): the before line is not flat,
    // while after compensation it lies on the zero line at the bottom.
    let x_position = &plots[0];
    assert!(
        num(&x_position["before"]["y1"]) - num(&x_position["before"]["y0"]) > 50.0,
        "{x_position}"
    );
    assert!(
        num(&x_position["after"]["y1"]) - num(&x_position["after"]["y0"]) < 3.0,
        "{x_position}"
    );
    // The table, as the browser shows it, against `kin compensate` over the same sweeps.
    let rows = probe["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 3, "{probe}");
    let shown = |r: &serde_json::Value, k: usize| -> f64 {
        r[k].as_str()
            .expect("cell text")
            .replace('−', "-")
            .trim()
            .parse()
            .unwrap_or_else(|_| panic!("a number: {r}"))
    };
    let sweeps = [
        ("X", "X=0:500:12.5,Y=200,Z=-150,dir_X=1"),
        ("Y", "X=250,Y=0:400:10,Z=-150,dir_X=1"),
        ("Z", "X=250,Y=200,Z=-300:0:7.5,dir_X=1"),
    ];
    for (r, (axis, grid)) in rows.iter().zip(sweeps) {
        assert_eq!(r[0], axis, "{r}");
        let csv = d.join(format!("sweep_{axis}.csv"));
        ok(&kin(&[
            "compensate",
            &s(&machine),
            "--fit",
            &s(&fit),
            "--grid",
            grid,
            "-o",
            &s(&csv),
        ]));
        let norm_max = |names: [&str; 3]| -> f64 {
            let cols: Vec<Vec<f64>> = names.iter().map(|n| column(&csv, n)).collect();
            assert_eq!(cols[0].len(), 41, "{grid}");
            (0..cols[0].len())
                .map(|i| cols.iter().map(|c| c[i] * c[i]).sum::<f64>().sqrt())
                .fold(0.0, f64::max)
        };
        let before = norm_max(["ex", "ey", "ez"]);
        let after = norm_max(["rest_ex", "rest_ey", "rest_ez"]);
        let tilt_before = norm_max(["erx", "ery", "erz"]);
        let tilt_after = norm_max(["rest_erx", "rest_ery", "rest_erz"]);
        // Shown to three significant digits; the remaining position error is rounding (pm).
        let close = |shown: f64, truth: f64| (shown - truth).abs() <= 0.005 * truth.abs() + 1e-6;
        assert!(close(shown(r, 1), before), "{axis}: {r} vs {before}");
        assert!(shown(r, 2) < 1e-6 && after < 1e-6, "{axis}: {r} vs {after}");
        assert!(
            close(shown(r, 3), tilt_before),
            "{axis}: {r} vs {tilt_before}"
        );
        assert!(
            close(shown(r, 4), tilt_after),
            "{axis}: {r} vs {tilt_after}"
        );
        assert_eq!(shown(r, 5), 3.0, "{r}");
    }
}

/// A mill with a tilting A axis carrying a C table, compensated with SINUMERIK tables of X and
/// Y while the grid holds Z, A and C at one value each. The tables' corrections must come from a
/// solve in which only X and Y move: applied as K3 describes the controller doing it (read by
/// the parser written from Siemens' manual above), they leave at every grid point at most
/// 0.3 µm more position error than the best correction by X and Y alone.
#[test]
fn sinumerik_tables_of_a_five_axis_mill_hold_only_what_their_axes_correct() {
    let source = &mill5(&[
        "X.tx = linear(X)",
        "A.ty = const",
        "A.tz = const",
        "A.rz = const",
        "C.tx = const",
        "C.ry = const",
    ]);
    let truth = "params {\n    X.tx = [20] um\n    A.ty = [15] um\n    A.tz = [-10] um\n    A.rz = [30] urad\n    C.tx = [12] um\n    C.ry = [25] urad\n}\n";
    let (d, machine, fit) = fitted_truth("sinumerik-5axis", source, truth);
    let (m, f) = (machine.to_str().unwrap(), fit.to_str().unwrap());
    let grid = "X=0:500:100,Y=0:400:100,Z=-100,A=30,C=45";
    let tables = d.join("tables");
    ok(&kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--grid",
        grid,
        "--table",
        "sinumerik",
        "-o",
        tables.to_str().unwrap(),
    ]));
    let note = std::fs::read_to_string(tables.join("kin-compensation.txt")).expect("note");
    assert!(note.contains("A=30 deg, C=45 deg"), "{note}");
    let (_, lec) = read_sinumerik(&tables.join("AX_EEC.INI"));
    let cec = if tables.join("NC_CEC.INI").exists() {
        read_sinumerik(&tables.join("NC_CEC.INI")).1
    } else {
        Vec::new()
    };
    // The fitted model, and its predicted error after the tables' corrections.
    let params = std::fs::read_to_string(fit.with_extension("params")).expect("FIT.params");
    let model = kin_model::Model::compile(source)
        .expect("compiles")
        .with_params(&params)
        .expect("binds");
    let mm = model.machine();
    let mut comp = kin_model::compensate::Compensator::new(
        mm,
        model.beta(),
        kin_model::compensate::Options::position(mm),
    )
    .expect("compensator");
    let mut worst = 0.0_f64;
    for xi in 0..=5 {
        for yi in 0..=4 {
            let (x, y) = (100.0 * xi as f64, 100.0 * yi as f64);
            let at = |name: &str| match name {
                "X" => x,
                "Y" => y,
                _ => -100.0,
            };
            let q = [
                x * 1e-3,
                y * 1e-3,
                -0.1,
                30f64.to_radians(),
                45f64.to_radians(),
            ];
            // Table values are the axes' errors (mm): the correction is their negative.
            let mut dq = [0.0; 5];
            for (k, axis) in ["X", "Y", "Z"].iter().enumerate() {
                dq[k] = -sinumerik_total(&lec, &cec, axis, 1.0, &at) * 1e-3;
            }
            let dirs = [1.0; 5];
            let state = kin_model::interp::State {
                q: &q,
                inputs: &[],
                lags: &[],
                time: 0.0,
                dirs: &dirs,
                tool: 0,
                tool_offset: None,
            };
            let rest = comp.remaining(&state, &dq).expect("remaining");
            // The best X and Y can do at this pose (Z, A and C held by the grid).
            let best = comp
                .compensate_with(&state, Some(&[true, true, false, false, false]))
                .expect("compensates")
                .after;
            let norm = |e: &[f64; 6]| (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
            worst = worst.max(norm(&rest) - norm(&best));
        }
    }
    // Every table here is exact at its points (linear and constant errors): beyond what X and
    // Y cannot correct, 0.3 µm is all that may remain. (A solve that also moved Z, A and C
    // left up to 4.3 µm more: corrections assuming moves no table makes.)
    assert!(
        worst < 0.3e-6,
        "{:.3} µm beyond what X and Y can do",
        worst * 1e6
    );
}

/// A poses file without the `dir_X` column (spec/data.md: optional) is compensated with X
/// taken as approached in its positive direction, as `--grid` does, and the output says so:
/// the corrections are those of the same file with `dir_X = +1`.
#[test]
fn poses_without_a_direction_column_are_taken_as_approached_in_plus() {
    let (d, machine, fit) = fitted("no-dir");
    let (m, f) = (machine.to_str().unwrap(), fit.to_str().unwrap());
    let bare = d.join("bare.csv");
    let plus = d.join("plus.csv");
    std::fs::write(&bare, "X,Y,Z\n0,0,-100\n250,200,-50\n500,400,-300\n").expect("write");
    std::fs::write(
        &plus,
        "X,dir_X,Y,Z\n0,+1,0,-100\n250,+1,200,-50\n500,+1,400,-300\n",
    )
    .expect("write");
    let (out_bare, out_plus) = (d.join("bare-out.csv"), d.join("plus-out.csv"));
    let run = kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--poses",
        bare.to_str().unwrap(),
        "-o",
        out_bare.to_str().unwrap(),
    ]);
    ok(&run);
    assert!(
        text(&run.stderr).contains("no dir_X column"),
        "{}",
        text(&run.stderr)
    );
    ok(&kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--poses",
        plus.to_str().unwrap(),
        "-o",
        out_plus.to_str().unwrap(),
    ]));
    let (a, b) = (column(&out_bare, "corr_X"), column(&out_plus, "corr_X"));
    assert_eq!(a.len(), 3);
    assert_eq!(a, b);
    assert!(a.iter().any(|v| v.abs() > 1.0), "{a:?}");
}

/// The 5-axis mill of the SINUMERIK test, corrected in position: by default only X, Y, Z move
/// (A and C stay where they are commanded, and the orientation error is what it was: the
/// rotation errors of this model do not depend on X, Y, Z); `--axes` lets A and C take part,
/// which then changes the orientation error. An unknown axis is a usage error.
#[test]
fn correct_position_keeps_the_rotary_axes_out_unless_asked() {
    let source = &mill5(&[
        "X.tx = linear(X)",
        "A.ty = const",
        "A.tz = const",
        "A.rz = const",
        "C.tx = const",
        "C.ry = const",
    ]);
    let truth = "params {\n    X.tx = [20] um\n    A.ty = [15] um\n    A.tz = [-10] um\n    A.rz = [30] urad\n    C.tx = [12] um\n    C.ry = [25] urad\n}\n";
    let (d, machine, fit) = fitted_truth("position-5axis", source, truth);
    let (m, f) = (machine.to_str().unwrap(), fit.to_str().unwrap());
    let grid = "X=0:500:250,Y=0:400:200,Z=-100,A=-30:30:30,C=0:90:45";
    let default = d.join("default.csv");
    let run = kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--grid",
        grid,
        "--correct",
        "position",
        "-o",
        default.to_str().unwrap(),
    ]);
    ok(&run);
    assert!(
        text(&run.stderr).contains("A, C held"),
        "{}",
        text(&run.stderr)
    );
    for axis in ["A", "C"] {
        assert!(column(&default, &format!("corr_{axis}"))
            .iter()
            .all(|v| *v == 0.0));
    }
    for k in ["ex", "ey", "ez"] {
        for v in column(&default, &format!("rest_{k}")) {
            assert!(v.abs() < 1e-3, "{k}: {v} um left");
        }
    }
    for k in ["erx", "ery", "erz"] {
        let (before, after) = (column(&default, k), column(&default, &format!("rest_{k}")));
        for (b, a) in before.iter().zip(&after) {
            assert!((a - b).abs() < 1e-3, "{k}: {b} -> {a} urad");
        }
    }
    let all = d.join("all.csv");
    ok(&kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--grid",
        grid,
        "--correct",
        "position",
        "--axes",
        "X,Y,Z,A,C",
        "-o",
        all.to_str().unwrap(),
    ]));
    let moved = column(&all, "corr_A")
        .iter()
        .chain(column(&all, "corr_C").iter())
        .fold(0.0_f64, |a, v| a.max(v.abs()));
    assert!(moved > 1.0, "A and C moved at most {moved} urad");
    let bad = kin(&[
        "compensate",
        m,
        "--fit",
        f,
        "--grid",
        grid,
        "--axes",
        "X,B",
        "-o",
        d.join("bad.csv").to_str().unwrap(),
    ]);
    assert_eq!(bad.status.code(), Some(2), "{}", text(&bad.stderr));
    assert!(text(&bad.stderr).contains("`B` is no axis"));
}

/// The 6-axis arm, whose tool point lies on the flange's roll axis J6, corrected in position
/// at 1 000 random poses: every pose converges with the position error cancelled and joint
/// corrections far inside the joints' ranges, J6 is named as not moved, or the run fails with
/// exit 1 naming the pose. Never an exit 0 with a correction beyond an axis range (the
/// unit-scaled column of rounding noise gave J6 10¹⁸ µrad).
#[test]
fn an_arm_corrected_in_position_converges_or_fails_on_every_pose() {
    let source = std::fs::read_to_string("examples/robot_6axis.kin").expect("example");
    let truth = "params {\n    J2.tx = [50] um\n    J3.rx = [40] urad\n    J5.rz = [60] urad\n    gripper.tx = [30] um\n    gripper.tz = [-20] um\n}\n";
    let d = dir().join("arm-1000");
    std::fs::create_dir_all(&d).expect("dir");
    let machine = d.join("robot.kin");
    let params = d.join("truth.params");
    std::fs::write(&machine, &source).expect("write");
    std::fs::write(&params, truth).expect("write");
    let (sim, fit, out) = (d.join("sim.csv"), d.join("fit.json"), d.join("out.csv"));
    let s = |p: &Path| p.to_str().expect("utf-8").to_string();
    ok(&kin(&[
        "simulate",
        &s(&machine),
        "--params",
        &s(&params),
        "--sample",
        "1000",
        "--seed",
        "5",
        "--components",
        "pose",
        "-o",
        &s(&sim),
    ]));
    ok(&kin(&["fit", &s(&machine), &s(&sim), "-o", &s(&fit)]));
    // A pose refused is taken out and the rest run again, so that every pose is either
    // corrected in the final run or refused with exit 1 naming its line.
    let poses = d.join("poses.csv");
    let mut lines: Vec<String> = std::fs::read_to_string(&sim)
        .expect("sim")
        .lines()
        .map(str::to_string)
        .collect();
    let data_rows = |lines: &[String]| lines.iter().filter(|l| !l.starts_with('#')).count() - 1;
    let total = data_rows(&lines);
    let mut refused = 0;
    let stderr = loop {
        std::fs::write(&poses, lines.join("\n") + "\n").expect("write");
        let run = kin(&[
            "compensate",
            &s(&machine),
            "--fit",
            &s(&fit),
            "--poses",
            &s(&poses),
            "--correct",
            "position",
            "-o",
            &s(&out),
        ]);
        let stderr = text(&run.stderr);
        if run.status.success() {
            break stderr;
        }
        assert_eq!(run.status.code(), Some(1), "{stderr}");
        let line: usize = stderr
            .split("line ")
            .nth(1)
            .and_then(|t| t.split(':').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no line named: {stderr}"));
        assert!(stderr.contains("error:"), "{stderr}");
        lines.remove(line - 1);
        refused += 1;
        assert!(
            refused <= 20,
            "{refused} of {total} poses refused; last: {stderr}"
        );
    };
    assert_eq!(total, 1000);
    assert!(stderr.contains("J6 has no leverage"), "{stderr}");
    // No correction beyond its joint's range (spans in degrees; J6 turns without end, one
    // turn). Near the wrist singularity (J5 ≈ 0, J4 and J6 aligned through the tool point) J4
    // takes up to some 0.2 rad: large, but a real solution of the linearised problem.
    let mut largest = 0.0_f64;
    for (axis, span) in [
        ("J1", 370.0),
        ("J2", 180.0),
        ("J3", 270.0),
        ("J4", 700.0),
        ("J5", 250.0),
        ("J6", 360.0),
    ] {
        let c = column(&out, &format!("corr_{axis}"));
        assert_eq!(c.len(), total - refused);
        for v in c {
            let deg = (v * 1e-6).to_degrees();
            assert!(v.is_finite() && deg.abs() < span, "{axis}: {v} urad");
            largest = largest.max(v.abs());
        }
    }
    eprintln!("largest joint correction {largest:.0} urad");
    for k in ["ex", "ey", "ez"] {
        for v in column(&out, &format!("rest_{k}")) {
            assert!(v.abs() < 1e-3, "{k}: {v} um left");
        }
    }
    eprintln!("{refused} of {total} poses refused with exit 1, the rest corrected");
}

/// A controller's correction of an axis (mm) at the positions of X and Y (mm).
type Correction = Box<dyn Fn(&str, f64, f64) -> f64>;

/// A 5-axis mill with a leadscrew (spline) error, straightness, a squareness and backlash, the
/// tables of LinuxCNC, ISG and SINUMERIK read by the parsers above (written from their
/// documentation) and applied as each controller does, on the **true** machine (exact
/// transforms of the simulated truth): at every grid pose the position error really left is
/// what `kin-leftover.csv` states for the tables, within 0.3 µm (the grid's points are the
/// tables' own, so no interpolation error enters); and the servo compensator's correction
/// (position, X Y Z moving) leaves what it predicts, within 0.3 µm.
#[test]
fn every_table_format_leaves_on_the_true_machine_what_kin_states() {
    let source = &mill5(&[
        "X.tx = spline(X, knots 2) + backlash(X)",
        "X.ty = straightness(X, knots 2)",
        "Y.ty = linear(Y)",
        "Y.rz = const",
        "A.ty = const",
        "C.tx = const",
    ]);
    let truth = "params {\n    X.tx = [12, -8, 5, 4, 3] um\n    X.ty = [6, -4, 3] um\n    Y.ty = [15] um\n    Y.rz = [40] urad\n    A.ty = [10] um\n    C.tx = [8] um\n}\n";
    let (d, machine, fit) = fitted_truth("five-formats", source, truth);
    let (m, f) = (machine.to_str().unwrap(), fit.to_str().unwrap());
    let truth_model = kin_model::Model::compile(source)
        .expect("compiles")
        .with_params(truth)
        .expect("truth");
    let tm = truth_model.machine();
    let mut it = kin_model::interp::Interpreter::new(tm).expect("interpreter");
    let mut errors = kin_model::kinematics::FrameErrors::zeros(tm);
    // The true position error when the controller moves the axes by `dq` at the commanded `q`.
    let mut truly_left = |q: &[f64; 5], dq: &[f64; 5]| -> f64 {
        let dirs = [1.0; 5];
        let pose = kin_model::kinematics::Pose {
            q,
            tool: 0,
            tool_offset: None,
        };
        let target = kin_model::exact::nominal_transform(tm, &pose).expect("nominal");
        let moved: Vec<f64> = q.iter().zip(dq).map(|(a, b)| a + b).collect();
        let state = kin_model::interp::State {
            q: &moved,
            inputs: &[],
            lags: &[],
            time: 0.0,
            dirs: &dirs,
            tool: 0,
            tool_offset: None,
        };
        it.frame_errors(&state, truth_model.beta(), &mut errors)
            .expect("errors");
        let actual = kin_model::exact::actual_transform(
            tm,
            &kin_model::kinematics::Pose { q: &moved, ..pose },
            &errors,
        )
        .expect("actual");
        let e = kin_model::exact::location_error(&target, &actual);
        (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt()
    };
    let grid = "X=0:500:100,Y=0:400:100,Z=-100,A=30,C=45";
    let mut worst = Vec::new();
    for format in ["linuxcnc", "isg-lsec", "sinumerik"] {
        let tables = d.join(format);
        ok(&kin(&[
            "compensate",
            m,
            "--fit",
            f,
            "--grid",
            grid,
            "--table",
            format,
            "-o",
            tables.to_str().unwrap(),
        ]));
        // The stated leftover per grid pose, in the grid's order (X slowest).
        let leftover = std::fs::read_to_string(tables.join("kin-leftover.csv")).expect("leftover");
        let stated: Vec<f64> = leftover
            .lines()
            .filter(|l| !l.starts_with('#') && !l.starts_with('X'))
            .map(|l| {
                l.split(',')
                    .nth(6)
                    .expect("tables column")
                    .parse()
                    .expect("number")
            })
            .collect();
        assert_eq!(stated.len(), 30, "{leftover}");
        // Each controller's correction of an axis at its position (mm), as it documents it.
        let correction: Correction = match format {
            "linuxcnc" => {
                let x = read_linuxcnc(&tables.join("X.comp"));
                let y = read_linuxcnc(&tables.join("Y.comp"));
                Box::new(move |axis, at, _| {
                    let rows = if axis == "X" { &x } else { &y };
                    // δ = p − value at a nominal position of the table (moving in +).
                    let row = rows
                        .iter()
                        .find(|r| (r[0] - at).abs() < 1e-9)
                        .expect("a table position");
                    row[0] - row[1]
                })
            }
            "isg-lsec" => {
                let lists: Vec<_> = ["X", "Y"]
                    .iter()
                    .map(|a| read_isg_list(&tables.join(format!("{a}.lis"))))
                    .collect();
                Box::new(move |axis, at, _| {
                    let list = &lists[if axis == "X" { 0 } else { 1 }];
                    let int = |k: &str| list[k].parse::<i64>().expect("integer");
                    let n = int("kw.ssfk.kw_nr_max") as usize;
                    let i = (0..n)
                        .find(|i| {
                            (int(&format!("kw.ssfk.table[{i}].setpoint")) as f64 * 1e-4 - at).abs()
                                < 1e-6
                        })
                        .expect("a setpoint");
                    // pos: actual − setpoint in 0.1 µm, minus the correction.
                    -(int(&format!("kw.ssfk.table[{i}].pos")) as f64) * 1e-4
                })
            }
            _ => {
                let (_, lec) = read_sinumerik(&tables.join("AX_EEC.INI"));
                let cec = if tables.join("NC_CEC.INI").exists() {
                    read_sinumerik(&tables.join("NC_CEC.INI")).1
                } else {
                    Vec::new()
                };
                Box::new(move |axis, x, y| {
                    let at = |name: &str| match name {
                        "X" => x,
                        "Y" => y,
                        _ => -100.0,
                    };
                    -sinumerik_total(&lec, &cec, axis, 1.0, &at)
                })
            }
        };
        let mut largest = 0.0f64;
        let mut k = 0;
        for xi in 0..=5 {
            for yi in 0..=4 {
                let (x, y) = (100.0 * xi as f64, 100.0 * yi as f64);
                let q = [
                    x * 1e-3,
                    y * 1e-3,
                    -0.1,
                    30f64.to_radians(),
                    45f64.to_radians(),
                ];
                let own =
                    |axis: &str, at: f64| correction(axis, at, if axis == "X" { y } else { x });
                let dq = [
                    if format == "sinumerik" {
                        correction("X", x, y)
                    } else {
                        own("X", x)
                    } * 1e-3,
                    if format == "sinumerik" {
                        correction("Y", x, y)
                    } else {
                        own("Y", y)
                    } * 1e-3,
                    0.0,
                    0.0,
                    0.0,
                ];
                let left = truly_left(&q, &dq) * 1e6;
                largest = largest.max((left - stated[k]).abs());
                k += 1;
            }
        }
        println!("{format}: the true leftover differs from the stated by at most {largest:.3} µm");
        assert!(largest < 0.3, "{format}: {largest} µm");
        worst.push(largest);
    }
    // The servo compensator of the fitted model, position only (X, Y, Z move), on the truth.
    let params = std::fs::read_to_string(fit.with_extension("params")).expect("FIT.params");
    let fitted = kin_model::Model::compile(source)
        .expect("compiles")
        .with_params(&params)
        .expect("fitted");
    let servo = fitted
        .compensator(kin_model::compensate::Options::position(fitted.machine()))
        .expect("servo");
    let mut largest = 0.0f64;
    for xi in 0..=5 {
        for yi in 0..=4 {
            let q = [
                0.1 * xi as f64,
                0.1 * yi as f64,
                -0.1,
                30f64.to_radians(),
                45f64.to_radians(),
            ];
            let dirs = [1.0; 5];
            let state = kin_model::interp::State {
                q: &q,
                inputs: &[],
                lags: &[],
                time: 0.0,
                dirs: &dirs,
                tool: 0,
                tool_offset: None,
            };
            let mut dq = [0.0; 5];
            let done = servo.compensate(&state, &mut dq).expect("compensates");
            assert_eq!((dq[3], dq[4]), (0.0, 0.0), "A and C held");
            let predicted =
                (done.after[0].powi(2) + done.after[1].powi(2) + done.after[2].powi(2)).sqrt();
            largest = largest.max((truly_left(&q, &dq) - predicted).abs() * 1e6);
        }
    }
    println!("servo: the true leftover differs from the predicted by at most {largest:.3} µm");
    assert!(largest < 0.3, "servo: {largest} µm");
}
