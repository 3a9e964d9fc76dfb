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
