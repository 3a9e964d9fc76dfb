//! `kin import dh`: the imported model's nominal kinematics equal the Denavit–Hartenberg
//! table's, computed here from the two conventions' definitions alone (standard: link i is
//! Rz(θᵢ + qᵢ)·Tz(dᵢ)·Tx(aᵢ)·Rx(αᵢ); modified, Craig: Rx(αᵢ₋₁)·Tx(aᵢ₋₁)·Rz(θᵢ + qᵢ)·Tz(dᵢ);
//! a prismatic joint adds qᵢ to dᵢ; a last `fixed` row is the flange in the same form).

use std::process::Command;

use kin_model::kinematics::Pose;
use nalgebra::{Matrix4, Rotation3, Vector3};

fn kin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .output()
        .expect("kin runs")
}

fn rz(t: f64) -> Matrix4<f64> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), t).to_homogeneous()
}
fn rx(t: f64) -> Matrix4<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), t).to_homogeneous()
}
fn tz(d: f64) -> Matrix4<f64> {
    Matrix4::new_translation(&Vector3::new(0.0, 0.0, d))
}
fn tx(a: f64) -> Matrix4<f64> {
    Matrix4::new_translation(&Vector3::new(a, 0.0, 0.0))
}

/// (a m, α rad, d m, θ rad, prismatic, fixed) per row.
type Table = Vec<(f64, f64, f64, f64, bool, bool)>;

fn fk(table: &Table, modified: bool, q: &[f64]) -> Matrix4<f64> {
    let mut t = Matrix4::identity();
    let mut k = 0;
    for &(a, alpha, d, theta, prismatic, fixed) in table {
        let (qr, qd) = match (fixed, prismatic) {
            (true, _) => (0.0, 0.0),
            (false, true) => (0.0, q[k]),
            (false, false) => (q[k], 0.0),
        };
        if !fixed {
            k += 1;
        }
        t *= if modified {
            rx(alpha) * tx(a) * rz(theta + qr) * tz(d + qd)
        } else {
            rz(theta + qr) * tz(d + qd) * tx(a) * rx(alpha)
        };
    }
    t
}

/// Imports `csv` and compares with `table` at 500 joint vectors within the ranges.
fn agree(csv: &str, modified: bool, table: &Table) -> f64 {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("robot.csv");
    std::fs::write(&path, csv).expect("write");
    let mut args = vec!["import", "dh", path.to_str().expect("utf-8")];
    if modified {
        args.extend(["--convention", "modified"]);
    }
    let out = kin(&args);
    let source = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let compiled = kin_compiler::compile(&source);
    let m = compiled
        .compiled
        .unwrap_or_else(|| panic!("{:?}\n{source}", compiled.diagnostics))
        .machine;
    let mut worst = 0.0f64;
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut uniform = |lo: f64, hi: f64| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        lo + (hi - lo) * ((state >> 11) as f64 / (1u64 << 53) as f64)
    };
    for _ in 0..500 {
        let q: Vec<f64> = m
            .axes
            .iter()
            .map(|a| uniform(a.range[0], a.range[1]))
            .collect();
        let t = kin_model::exact::nominal_transform(
            &m,
            &Pose {
                q: &q,
                tool: 0,
                tool_offset: None,
            },
        )
        .expect("nominal");
        let u = fk(table, modified, &q);
        worst = worst.max((t - u).amax());
    }
    worst
}

#[test]
fn the_ur10_standard_table_imports_with_its_forward_kinematics_to_1e_12() {
    let csv = std::fs::read_to_string("examples/dh/ur10.csv").expect("example");
    let d = std::f64::consts::PI / 180.0;
    let table: Table = vec![
        (0.0, 90.0 * d, 0.1273, 0.0, false, false),
        (-0.612, 0.0, 0.0, 0.0, false, false),
        (-0.5723, 0.0, 0.0, 0.0, false, false),
        (0.0, 90.0 * d, 0.163941, 0.0, false, false),
        (0.0, -90.0 * d, 0.1157, 0.0, false, false),
        (0.0, 0.0, 0.0922, 0.0, false, false),
    ];
    let worst = agree(&csv, false, &table);
    assert!(worst < 1e-12, "{worst}");
}

#[test]
fn the_puma_modified_table_imports_with_its_forward_kinematics_to_1e_12() {
    let csv = std::fs::read_to_string("examples/dh/puma560.csv").expect("example");
    let d = std::f64::consts::PI / 180.0;
    let table: Table = vec![
        (0.0, 0.0, 0.0, 0.0, false, false),
        (0.0, -90.0 * d, 0.0, 0.0, false, false),
        (0.4318, 0.0, 0.1491, 0.0, false, false),
        (-0.0203, -90.0 * d, 0.4331, 0.0, false, false),
        (0.0, 90.0 * d, 0.0, 0.0, false, false),
        (0.0, -90.0 * d, 0.0, 0.0, false, false),
    ];
    let worst = agree(&csv, true, &table);
    assert!(worst < 1e-12, "{worst}");
}

#[test]
fn prismatic_joints_offsets_and_a_flange_row_in_both_conventions() {
    // A SCARA with a quill, zero offsets and a tool row; lengths in m, angles in rad.
    let csv = "joint;type;a[m];alpha[rad];d[m];theta[rad];lower;upper\n\
               J1;revolute;0.325;0;0.4;0.1;-150;150\n\
               J2;revolute;0.275;3.141592653589793;0;-0.2;-150;150\n\
               Z;prismatic;0;0;0.05;0.3;0;200\n\
               tool;fixed;0.02;0.5;-0.1;0.7;;\n";
    let table: Table = vec![
        (0.325, 0.0, 0.4, 0.1, false, false),
        (0.275, std::f64::consts::PI, 0.0, -0.2, false, false),
        (0.0, 0.0, 0.05, 0.3, true, false),
        (0.02, 0.5, -0.1, 0.7, false, true),
    ];
    for modified in [false, true] {
        let worst = agree(csv, modified, &table);
        assert!(worst < 1e-12, "modified {modified}: {worst}");
    }
}

#[test]
fn a_bad_cell_is_reported_at_its_line_and_column() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("bad.csv");
    std::fs::write(
        &path,
        "# a comment\na,alpha,d,theta\n0,90,127.3,0\n0,ninety,0,0\n",
    )
    .expect("write");
    let out = kin(&["import", "dh", path.to_str().expect("utf-8")]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("bad.csv:4:3: `ninety` is not a finite number"),
        "{stderr}"
    );
    std::fs::write(&path, "a,alpha,d\n0,90,127.3\n").expect("write");
    let out = kin(&["import", "dh", path.to_str().expect("utf-8")]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("no `theta` column"), "{stderr}");
}

fn ry(t: f64) -> Matrix4<f64> {
    Rotation3::from_axis_angle(&Vector3::y_axis(), t).to_homogeneous()
}

/// A `# base [mm, deg]: x y z roll pitch yaw` frame as `kin export dh` documents it (URDF's
/// fixed axes: R = Rz(yaw)·Ry(pitch)·Rx(roll)).
fn frame_of(values: &str) -> Matrix4<f64> {
    let v: Vec<f64> = values
        .split_whitespace()
        .map(|w| w.parse().expect("number"))
        .collect();
    assert_eq!(v.len(), 6, "{values}");
    let d = std::f64::consts::PI / 180.0;
    Matrix4::new_translation(&Vector3::new(v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3))
        * rz(v[5] * d)
        * ry(v[4] * d)
        * rx(v[3] * d)
}

/// The exported table read as its header documents it: base, tool, and per row
/// Rz(θ + q)·Tz(d)·Tx(a)·Rx(α)·Ry(β) (d + q for a prismatic joint).
fn exported_fk(csv: &str, q: &[f64]) -> Matrix4<f64> {
    let mut base = Matrix4::identity();
    let mut tool = Matrix4::identity();
    let mut rows = Vec::new();
    let mut header: Vec<String> = Vec::new();
    for line in csv.lines() {
        if let Some(v) = line.strip_prefix("# base [mm, deg]:") {
            base = frame_of(v);
        } else if let Some(rest) = line.strip_prefix("# tool ") {
            let (_, v) = rest.split_once("[mm, deg]:").expect("tool frame");
            tool = frame_of(v);
        } else if line.starts_with('#') {
        } else if header.is_empty() {
            header = line.split(',').map(str::to_string).collect();
        } else {
            rows.push(line.split(',').map(str::to_string).collect::<Vec<_>>());
        }
    }
    let col = |name: &str| {
        header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no {name} in {header:?}"))
    };
    let d = std::f64::consts::PI / 180.0;
    let mut t = base;
    for (row, qk) in rows.iter().zip(q) {
        let v = |name: &str| row[col(name)].parse::<f64>().expect("number");
        let prismatic = row[col("type")] == "prismatic";
        let (qr, qd) = if prismatic { (0.0, *qk) } else { (*qk, 0.0) };
        t *= rz(v("theta[deg]") * d + qr)
            * tz(v("d[mm]") * 1e-3 + qd)
            * tx(v("a[mm]") * 1e-3)
            * rx(v("alpha[deg]") * d)
            * ry(v("beta[deg]") * d);
    }
    t * tool
}

/// Imports the DH table `table_csv`, sets every constant of its default error model to tens of
/// µm or µrad, exports the calibrated robot with `kin export dh`, and compares at 300 joint
/// vectors kin's exact model of those errors with the exported table's forward kinematics
/// (computed here from its documented convention) and with the nominal model of the table
/// read back by `kin import dh`. Returns (table, read back, how far the errors move the tool,
/// rows with a Hayati β, the export's summary).
fn export_agrees(table_csv: &str) -> (f64, f64, f64, usize, String) {
    let dir = tempfile::tempdir().expect("temp dir");
    let nominal = dir.path().join("nominal.csv");
    std::fs::write(&nominal, table_csv).expect("write");
    let out = kin(&["import", "dh", nominal.to_str().expect("utf-8")]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let source = String::from_utf8_lossy(&out.stdout).into_owned();
    let mut params = String::from("params {\n");
    for (k, line) in source
        .lines()
        .filter_map(|l| l.trim().strip_suffix(" = const"))
        .enumerate()
    {
        let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
        let size = 20.0 + 13.0 * (k % 5) as f64;
        let unit = if line.contains(".r") { "urad" } else { "um" };
        params.push_str(&format!("    {line}[0] = {} {unit}\n", sign * size));
    }
    params.push_str("}\n");
    let model = dir.path().join("robot.kin");
    std::fs::write(&model, format!("{source}{params}")).expect("write");
    let table = dir.path().join("robot_dh.csv");
    let out = kin(&[
        "export",
        "dh",
        model.to_str().expect("utf-8"),
        "-o",
        table.to_str().expect("utf-8"),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(&table).expect("table");
    let hayati = csv
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("joint,"))
        .filter(|l| l.split(',').nth(6).is_some_and(|b| b != "0"))
        .count();
    let compiled = kin_compiler::compile(&format!("{source}{params}"));
    let m = compiled
        .compiled
        .unwrap_or_else(|| panic!("{:?}", compiled.diagnostics))
        .machine;
    let out = kin(&["import", "dh", table.to_str().expect("utf-8")]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let back = kin_compiler::compile(&String::from_utf8_lossy(&out.stdout))
        .compiled
        .expect("the imported table compiles")
        .machine;
    let mut it = kin_model::interp::Interpreter::new(&m).expect("interpreter");
    let mut errors = kin_model::kinematics::FrameErrors::zeros(&m);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = |lo: f64, hi: f64| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        lo + (hi - lo) * ((state >> 11) as f64 / (1u64 << 53) as f64)
    };
    let (mut worst, mut worst_back, mut moved) = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..300 {
        let q: Vec<f64> = m
            .axes
            .iter()
            .map(|a| uniform(a.range[0], a.range[1]))
            .collect();
        let dirs = vec![1.0; q.len()];
        let s = kin_model::interp::State {
            q: &q,
            inputs: &[],
            lags: &[],
            time: 0.0,
            dirs: &dirs,
            tool: 0,
            tool_offset: None,
        };
        it.frame_errors(&s, &m.beta, &mut errors).expect("errors");
        let pose = Pose {
            q: &q,
            tool: 0,
            tool_offset: None,
        };
        let truth = kin_model::exact::actual_transform(&m, &pose, &errors).expect("exact");
        let nominal = kin_model::exact::nominal_transform(&m, &pose).expect("nominal");
        let read_back = kin_model::exact::nominal_transform(&back, &pose).expect("nominal");
        worst = worst.max((truth - exported_fk(&csv, &q)).amax());
        worst_back = worst_back.max((truth - read_back).amax());
        moved = moved.max((truth - nominal).amax());
    }
    (worst, worst_back, moved, hayati, stdout)
}

/// `kin export dh` of a calibrated UR10 (the parallel shoulder and elbow joints tilted by their
/// errors, so Hayati's β carries the tilts) and of a SCARA with a prismatic quill: the table's
/// forward kinematics equal kin's exact model of the errors to 1e-9 m, and so does the table
/// read back by `kin import dh`.
#[test]
fn a_calibrated_robot_exports_as_a_dh_table_with_its_kinematics() {
    let ur10 = std::fs::read_to_string("examples/dh/ur10.csv").expect("example");
    let scara = "joint,type,a[m],alpha[rad],d[m],theta[rad],lower,upper\n\
                 J1,revolute,0.325,0,0.4,0.1,-150,150\n\
                 J2,revolute,0.275,3.141592653589793,0,-0.2,-150,150\n\
                 Z,prismatic,0,0,0.05,0.3,0,200\n\
                 J4,revolute,0,0,0.1,0,-170,170\n";
    for (name, csv, hayati_min) in [("ur10", ur10.as_str(), 2), ("scara", scara, 1)] {
        let (worst, back, moved, hayati, summary) = export_agrees(csv);
        println!("export dh {name}: table {worst:.1e}, read back {back:.1e}, errors move {moved:.1e}, {hayati} Hayati rows");
        assert!(moved > 1e-5, "{name}: the errors are seen: {moved}");
        assert!(
            worst < 1e-9,
            "{name}: the table's kinematics differ by {worst}"
        );
        assert!(back < 1e-9, "{name}: read back, they differ by {back}");
        assert!(hayati >= hayati_min, "{name}: {summary}");
    }
}
