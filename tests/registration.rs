//! `kin fit` of absolute positions (spec/data.md, "Absolute positions"): the bundled UR10-class
//! example measured by a tracker in its own frame. The data are made here with the exact
//! simulator and a known truth (a tracker 1.5 m away and turned, a reflector 130 mm off the
//! flange); `examples/ur10/tracker.csv` is that file, kept equal to what this generator writes.

use std::path::Path;
use std::process::Command;

use kin_compiler::compile;
use kin_model::exact;
use kin_model::interp::{Interpreter, State};
use kin_model::kinematics::{FrameErrors, Pose};
use nalgebra::{Rotation3, Vector3};

const MODEL: &str = "examples/ur10/ur10.kin";
const DATA: &str = "examples/ur10/tracker.csv";

/// J2..J5 zero offsets (rad), J3 and J4 length errors (m): the example's β.
const BETA: [f64; 6] = [4e-4, -3e-4, 5e-4, -2e-4, 3e-4, -2e-4];
/// The tracker: wr → tracker rotation vector (rad) and translation (m).
const TURN: [f64; 3] = [0.02, -0.05, 1.2];
const SHIFT: [f64; 3] = [-1.2, 0.9, -0.35];
/// The reflector on the flange, m.
const TARGET: [f64; 3] = [0.04, 0.06, 0.11];
const NOISE_MM: f64 = 0.02;

/// A deterministic sequence in [0, 1) (the tests' dependencies have no random generator).
struct Sequence(u64);

impl Sequence {
    fn next(&mut self) -> f64 {
        // SplitMix64.
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A standard normal deviate (Box–Muller).
    fn normal(&mut self) -> f64 {
        let u = self.next().max(1e-300);
        let v = self.next();
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// The tracker file: `n` poses, the reflector's actual position (exact transforms) in the
/// tracker's frame with noise, in mm and degrees.
fn tracker_csv(n: usize) -> String {
    tracker_csv_with(n, 140.0)
}

/// As [`tracker_csv`], with the elbow J3 within ±`elbow` degrees (the others within ±140°).
fn tracker_csv_with(n: usize, elbow: f64) -> String {
    let text = std::fs::read_to_string(MODEL).expect("the example model");
    let out = compile(&text);
    let c = out.compiled.expect("the example compiles");
    let m = &c.machine;
    let mut it = Interpreter::new(m).expect("interpreter");
    let mut errors = FrameErrors::zeros(m);
    let rotation = Rotation3::new(Vector3::from(TURN));
    let mut seq = Sequence(7);
    let mut csv = String::from(
        "# A laser tracker's readings of a reflector on the flange, in the tracker's frame\n\
         # (simulated with known truth by tests/registration.rs)\n\
         J1[deg],J2[deg],J3[deg],J4[deg],J5[deg],J6[deg],px[mm],py[mm],pz[mm]\n",
    );
    let dirs = [f64::NAN; 6];
    for _ in 0..n {
        // Whole hundredths of a degree, as a controller reports them.
        let deg: Vec<f64> = (0..6)
            .map(|a| {
                let span = if a == 2 { elbow } else { 140.0 };
                ((seq.next() * 2.0 - 1.0) * span * 100.0).round() / 100.0
            })
            .collect();
        let q: Vec<f64> = deg.iter().map(|d| d.to_radians()).collect();
        let state = State {
            q: &q,
            inputs: &[],
            lags: &[],
            time: 0.0,
            dirs: &dirs,
            tool: 0,
            tool_offset: Some(TARGET),
        };
        it.frame_errors(&state, &BETA, &mut errors).expect("errors");
        let pose = Pose {
            q: &q,
            tool: 0,
            tool_offset: Some(TARGET),
        };
        let t = exact::actual_transform(m, &pose, &errors).expect("transform");
        let p = Vector3::new(t[(0, 3)], t[(1, 3)], t[(2, 3)]);
        let y = rotation * p + Vector3::from(SHIFT);
        let cells: Vec<String> = deg
            .iter()
            .map(|d| format!("{d}"))
            .chain((0..3).map(|c| format!("{:.4}", y[c] * 1e3 + NOISE_MM * seq.normal())))
            .collect();
        csv.push_str(&cells.join(","));
        csv.push('\n');
    }
    csv
}

#[test]
fn the_example_tracker_file_is_the_generators() {
    let made = tracker_csv(60);
    if std::env::var_os("KIN_BLESS").is_some() {
        std::fs::write(DATA, &made).expect("write the example");
    }
    let kept = std::fs::read_to_string(DATA).expect("examples/ur10/tracker.csv");
    assert!(
        kept == made,
        "{DATA} differs from the generator (KIN_BLESS=1 rewrites it)"
    );
}

fn kin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .output()
        .expect("kin runs")
}

#[test]
fn kin_fit_finds_the_tracker_and_the_reflector() {
    let dir = tempfile::tempdir().expect("temp dir");
    let json = dir.path().join("FIT.json");
    let json_arg = json.to_str().expect("utf-8 path");
    // A copy of the model: a fit records its history beside the model.
    let model = dir.path().join("ur10.kin");
    std::fs::copy(MODEL, &model).expect("copy the model");
    let model = model.to_str().expect("utf-8 path");
    let out = kin(&["fit", model, DATA, "-o", json_arg, "--holdout", "0.25"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("instrument of"), "{stdout}");
    assert!(stdout.contains("target at"), "{stdout}");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("FIT.json")).expect("json");
    let reg = &doc["registration"][0];
    let v3 = |v: &serde_json::Value| -> [f64; 3] {
        std::array::from_fn(|k| v[k].as_f64().expect("number"))
    };
    // The tracker's origin in wr: −Rᵀt, in mm; within 3 u (its rotation's uncertainty times
    // the 1.5 m lever, plus the shift's) of the truth.
    let r = Rotation3::new(Vector3::from(TURN));
    let origin = -(r.inverse() * Vector3::from(SHIFT)) * 1e3;
    let found = v3(&reg["instrument_position"]);
    let shift_u = v3(&reg["shift_u"]);
    let rotation_u = v3(&reg["rotation_u"]);
    let lever = origin.norm();
    for k in 0..3 {
        let u = shift_u[k] + lever * rotation_u[k].to_radians() * 3.0_f64.sqrt();
        assert!(
            (found[k] - origin[k]).abs() <= 3.0 * u,
            "tracker origin {k}: {} vs {} ± {u}",
            found[k],
            origin[k]
        );
    }
    let target = v3(&reg["targets"][0]["offset"]);
    let target_u = v3(&reg["targets"][0]["offset_u"]);
    for k in 0..3 {
        assert!(
            (target[k] - TARGET[k] * 1e3).abs() <= 3.0 * target_u[k],
            "reflector {k}: {} ± {}",
            target[k],
            target_u[k]
        );
    }
    // The held-out quarter, registered with the fitted placement, at the noise.
    let rms = doc["validation"][0]["rms"]
        .as_f64()
        .expect("validation rms");
    assert!(
        rms < 1.3 * NOISE_MM * 1e3 && rms > 0.7 * NOISE_MM * 1e3,
        "held-out RMS {rms} um"
    );
}

#[test]
fn an_incomplete_position_is_a_located_error() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("half.csv");
    std::fs::write(&path, "J1,J2,J3,J4,J5,J6,px,py\n0,10,20,30,40,50,1000,20\n").expect("write");
    let model = dir.path().join("ur10.kin");
    std::fs::copy(MODEL, &model).expect("copy the model");
    let out = kin(&[
        "fit",
        model.to_str().expect("utf-8"),
        path.to_str().expect("utf-8"),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("missing: pz"), "{stderr}");
    assert!(Path::new(MODEL).exists());
}

#[test]
fn eval_nominal_prints_the_published_ur10_forward_kinematics() {
    // UR10 standard DH at zero: the tool at (a2 + a3, −(d4 + d6), d1 − d5); upright (J2 = J4 =
    // −90°): straight up at d1 − a2 − a3 + d5, with d4 + d6 sideways.
    let dir = tempfile::tempdir().expect("temp dir");
    let poses = dir.path().join("q.csv");
    std::fs::write(&poses, "J1,J2,J3,J4,J5,J6\n0,0,0,0,0,0\n0,-90,0,-90,0,0\n").expect("write");
    let out = kin(&[
        "eval",
        MODEL,
        poses.to_str().expect("utf-8"),
        "--nominal",
        "--components",
        "position",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    let rows: Vec<Vec<f64>> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("J1"))
        .map(|l| l.split(',').map(|c| c.parse().expect("number")).collect())
        .collect();
    let header = text.lines().find(|l| l.starts_with("J1")).expect("header");
    let at = |name: &str| {
        header
            .split(',')
            .position(|c| c.starts_with(&format!("{name}[")))
            .expect("column")
    };
    let (d1, a2, a3, d4, d5, d6) = (127.3, -612.0, -572.3, 163.941, 115.7, 92.2);
    let expected = [
        [a2 + a3, -(d4 + d6), d1 - d5],
        [0.0, -(d4 + d6), d1 - a2 - a3 + d5],
    ];
    for (row, want) in rows.iter().zip(expected) {
        for (k, name) in ["px", "py", "pz"].iter().enumerate() {
            let got = row[at(name)];
            assert!((got - want[k]).abs() < 1e-9, "{name}: {got} vs {}", want[k]);
        }
    }
}

#[test]
fn a_straight_elbow_leaves_the_zero_offsets_weakly_determined_and_kin_fit_says_so() {
    // With J3 within ±2°, the upper arm and the forearm stay on one line: turning the shoulder
    // or the elbow by a zero offset then moves the reflector nearly alike, and the plan
    // determines those two offsets well only together (their standard errors a hundred times
    // what each would have alone), while the full example's plan separates them.
    let dir = tempfile::tempdir().expect("temp dir");
    let data = dir.path().join("straight.csv");
    std::fs::write(&data, tracker_csv_with(60, 2.0)).expect("write");
    let model = dir.path().join("ur10.kin");
    std::fs::copy(MODEL, &model).expect("copy the model");
    let json = dir.path().join("FIT.json");
    let out = kin(&[
        "fit",
        model.to_str().expect("utf-8"),
        data.to_str().expect("utf-8"),
        "-o",
        json.to_str().expect("utf-8"),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(
        stdout.contains("warning: the data barely determine"),
        "{stdout}"
    );
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("FIT.json")).expect("json");
    let weak = doc["weak"].as_array().expect("weak");
    let named: Vec<&str> = weak
        .iter()
        .flat_map(|w| w["members"].as_array().into_iter().flatten())
        .filter_map(|m| m.as_str())
        .collect();
    assert!(
        named.contains(&"J2.rz[0]") && named.contains(&"J3.rz[0]"),
        "{named:?}"
    );
    // The full plan (the example) has none.
    let full = kin(&["fit", model.to_str().expect("utf-8"), DATA]);
    let stdout = String::from_utf8_lossy(&full.stdout);
    assert!(!stdout.contains("barely"), "{stdout}");
}

/// `kin check --plan` of a file of absolute positions counts the registration's unknowns: with
/// two reflectors on the flange, a constant offset of the flange is taken up by both targets'
/// fitted offsets, as the fit finds (it used to call it determined: the named targets' offsets
/// were not eliminated with the instrument's placement).
#[test]
fn a_plan_of_absolute_positions_counts_the_registration() {
    let dir = tempfile::tempdir().expect("temp dir");
    let source = std::fs::read_to_string("examples/ur10/ur10.kin").expect("example");
    let model = dir.path().join("ur10.kin");
    std::fs::write(
        &model,
        source.replacen(
            "    errors {\n",
            "    errors {\n        flange.ty = const\n",
            1,
        ),
    )
    .expect("write");
    // Every pose of the example measured at two reflectors, 50 mm apart.
    let text = std::fs::read_to_string("examples/ur10/tracker.csv").expect("example");
    let mut two = String::new();
    for line in text.lines() {
        if line.starts_with('#') {
            two.push_str(line);
        } else if line.starts_with("J1") {
            two.push_str(&format!("{line},target"));
        } else {
            let mut cells: Vec<String> = line.split(',').map(str::to_string).collect();
            two.push_str(&format!("{line},A\n"));
            let px: f64 = cells[6].parse().expect("px");
            cells[6] = format!("{}", px + 50.0);
            two.push_str(&format!("{},B", cells.join(",")));
        }
        two.push('\n');
    }
    let data = dir.path().join("two.csv");
    std::fs::write(&data, two).expect("write");
    let (m, d) = (
        model.to_str().expect("utf-8"),
        data.to_str().expect("utf-8"),
    );
    let out = kin(&["check", m, "--plan", d]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("determines 6 of 7") && stdout.contains("flange.ty"),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The fit agrees: one direction short, flange.ty against a target's offset.
    let out = kin(&["fit", m, d]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("flange.ty") && stderr.contains("target"),
        "{stderr}"
    );
}
