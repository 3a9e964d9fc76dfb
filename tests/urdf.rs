//! `kin import urdf`: imported chains agree with the URDF's own forward kinematics.
//!
//! The URDF side is computed here from the format's documentation alone (ROS wiki,
//! urdf/XML/joint): the child link's frame is `Trans(xyz) · Rz(yaw) · Ry(pitch) · Rx(roll)` in
//! the parent's, followed by the joint motion about or along the unit axis given in the child
//! frame. It shares nothing with the importer but the XML parser.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use kin_estimate::identify::Observe;
use kin_model::kinematics::Pose;
use kin_standards::urdf::{self, Options};

type M4 = [[f64; 4]; 4];

fn mul(a: &M4, b: &M4) -> M4 {
    let mut c = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            c[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn identity() -> M4 {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

fn from_rt(r: [[f64; 3]; 3], t: [f64; 3]) -> M4 {
    let mut m = identity();
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = r[i][j];
        }
        m[i][3] = t[i];
    }
    m
}

/// Rotation by `angle` about the unit vector `u` (Rodrigues).
fn axis_angle(u: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let [x, y, z] = u;
    let v = 1.0 - c;
    [
        [c + x * x * v, x * y * v - z * s, x * z * v + y * s],
        [y * x * v + z * s, c + y * y * v, y * z * v - x * s],
        [z * x * v - y * s, z * y * v + x * s, c + z * z * v],
    ]
}

/// `<origin xyz rpy>`: fixed-axis roll about x, then pitch about y, then yaw about z.
fn origin(xyz: [f64; 3], rpy: [f64; 3]) -> M4 {
    let roll = from_rt(axis_angle([1.0, 0.0, 0.0], rpy[0]), [0.0; 3]);
    let pitch = from_rt(axis_angle([0.0, 1.0, 0.0], rpy[1]), [0.0; 3]);
    let yaw = from_rt(axis_angle([0.0, 0.0, 1.0], rpy[2]), [0.0; 3]);
    mul(
        &from_rt(axis_angle([1.0, 0.0, 0.0], 0.0), xyz),
        &mul(&yaw, &mul(&pitch, &roll)),
    )
}

#[derive(Debug, Clone)]
struct UrdfJoint {
    kind: String,
    parent: String,
    origin: M4,
    axis: [f64; 3],
    limits: Option<(f64, f64)>,
}

/// The joints of a URDF text by child link, and by name.
struct Urdf {
    by_child: HashMap<String, (String, UrdfJoint)>,
}

fn triple(node: roxmltree::Node<'_, '_>, name: &str, default: [f64; 3]) -> [f64; 3] {
    node.attribute(name).map_or(default, |v| {
        let w: Vec<f64> = v.split_whitespace().map(|x| x.parse().unwrap()).collect();
        [w[0], w[1], w[2]]
    })
}

fn read_urdf(text: &str) -> Urdf {
    let doc = roxmltree::Document::parse(text).unwrap();
    let mut by_child = HashMap::new();
    for j in doc
        .root_element()
        .children()
        .filter(|n| n.has_tag_name("joint"))
    {
        let child = |tag: &str| {
            j.children()
                .find(|n| n.has_tag_name(tag))
                .map(|n| n.attribute("link").unwrap().to_string())
                .unwrap()
        };
        let o = j.children().find(|n| n.has_tag_name("origin"));
        let origin = o.map_or(identity(), |o| {
            origin(triple(o, "xyz", [0.0; 3]), triple(o, "rpy", [0.0; 3]))
        });
        let a = j
            .children()
            .find(|n| n.has_tag_name("axis"))
            .map_or([1.0, 0.0, 0.0], |a| triple(a, "xyz", [1.0, 0.0, 0.0]));
        let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        let limits = j.children().find(|n| n.has_tag_name("limit")).map(|l| {
            (
                l.attribute("lower").unwrap().parse().unwrap(),
                l.attribute("upper").unwrap().parse().unwrap(),
            )
        });
        by_child.insert(
            child("child"),
            (
                j.attribute("name").unwrap().to_string(),
                UrdfJoint {
                    kind: j.attribute("type").unwrap().to_string(),
                    parent: child("parent"),
                    origin,
                    axis: [a[0] / n, a[1] / n, a[2] / n],
                    limits,
                },
            ),
        );
    }
    Urdf { by_child }
}

impl Urdf {
    /// The moving joints from `base` to `tip`, base first: (name, joint).
    fn chain(&self, base: &str, tip: &str) -> Vec<(String, UrdfJoint)> {
        let mut out = Vec::new();
        let mut link = tip.to_string();
        while link != base {
            let (name, j) = self.by_child.get(&link).unwrap().clone();
            link = j.parent.clone();
            out.push((name, j));
        }
        out.reverse();
        out
    }

    /// `T(base → tip)` at joint positions `q` (by joint name; m or rad).
    fn fk(&self, base: &str, tip: &str, q: &HashMap<String, f64>) -> M4 {
        let mut t = identity();
        for (name, j) in self.chain(base, tip) {
            t = mul(&t, &j.origin);
            let motion = match j.kind.as_str() {
                "fixed" => identity(),
                "prismatic" => from_rt(
                    axis_angle([1.0, 0.0, 0.0], 0.0),
                    j.axis.map(|a| a * q[&name]),
                ),
                _ => from_rt(axis_angle(j.axis, q[&name]), [0.0; 3]),
            };
            t = mul(&t, &motion);
        }
        t
    }
}

/// A small deterministic generator (xorshift), so the test needs no crate of its own.
struct Rng(u64);
impl Rng {
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        lo + (hi - lo) * ((self.0 >> 11) as f64 / (1u64 << 53) as f64)
    }
}

/// Largest position (m) and rotation (rad) difference between the imported model's nominal
/// `T(wr → tl)`, premultiplied by `before`, and the URDF's `T(base → tip)` over `n` random
/// joint vectors within the limits (continuous joints over ±2 turns).
fn compare(kin: &str, urdf: &Urdf, base: &str, tip: &str, before: M4, n: usize) -> (f64, f64) {
    let compiled = kin_compiler::compile(kin);
    let machine = compiled
        .compiled
        .unwrap_or_else(|| panic!("{:#?}\n{kin}", compiled.diagnostics))
        .machine;
    let chain = urdf.chain(base, tip);
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let (mut dp, mut dr) = (0.0f64, 0.0f64);
    for _ in 0..n {
        let mut q = HashMap::new();
        for (name, j) in chain.iter().filter(|(_, j)| j.kind != "fixed") {
            let (lo, hi) = match (j.kind.as_str(), j.limits) {
                ("continuous", _) | (_, None) => {
                    (-4.0 * std::f64::consts::PI, 4.0 * std::f64::consts::PI)
                }
                (_, Some(l)) => l,
            };
            q.insert(name.clone(), rng.uniform(lo, hi));
        }
        // kin's axes are the URDF joints, named alike (these files use kin-safe names).
        let qk: Vec<f64> = machine.axes.iter().map(|a| q[&a.name]).collect();
        let pose = Pose {
            q: &qk,
            tool: 0,
            tool_offset: None,
        };
        let t = kin_model::exact::nominal_transform(&machine, &pose).unwrap();
        let mut tk = identity();
        for i in 0..4 {
            for j in 0..4 {
                tk[i][j] = t[(i, j)];
            }
        }
        let tk = mul(&before, &tk);
        let tu = urdf.fk(base, tip, &q);
        for i in 0..3 {
            dp = dp.max((tk[i][3] - tu[i][3]).abs());
        }
        // The angle of R_kin R_urdfᵀ, from its trace.
        let mut trace = 0.0;
        for i in 0..3 {
            for k in 0..3 {
                trace += tk[i][k] * tu[i][k];
            }
        }
        let angle = ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos();
        // acos loses precision near 0: use the skew part instead there.
        let mut skew = 0.0f64;
        for (a, b) in [(1, 2), (2, 0), (0, 1)] {
            let mut s = 0.0;
            for k in 0..3 {
                s += tk[b][k] * tu[a][k] - tk[a][k] * tu[b][k];
            }
            skew += (s / 2.0).powi(2);
        }
        dr = dr.max(if angle < 1e-3 { skew.sqrt() } else { angle });
    }
    (dp, dr)
}

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

fn kin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kin"))
}

#[test]
fn a_ur5_imports_with_the_urdf_forward_kinematics_to_1e_9() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ur5.kin");
    let run = kin()
        .args(["import", "urdf"])
        .arg(repo("examples/urdf/ur5.urdf"))
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&run.stderr)
    );
    // The `base` leaf has no moving joint above it: tool0 is the tip.
    assert!(
        stdout.contains("6 moving joints from link `base_link` to link `tool0`"),
        "{stdout}"
    );
    let kin_text = std::fs::read_to_string(&out).unwrap();
    let urdf = read_urdf(&std::fs::read_to_string(repo("examples/urdf/ur5.urdf")).unwrap());
    let (dp, dr) = compare(&kin_text, &urdf, "base_link", "tool0", identity(), 2000);
    eprintln!("UR5, 2000 joint vectors: largest difference {dp:e} m, {dr:e} rad");
    assert!(
        dp <= 1e-9 && dr <= 1e-9,
        "position {dp:e} m, rotation {dr:e} rad\n{kin_text}"
    );

    // The default error model passes `kin check`, identifiability included.
    let check = kin().arg("check").arg(&out).output().unwrap();
    assert!(
        check.status.success(),
        "{}{}",
        String::from_utf8_lossy(&check.stdout),
        String::from_utf8_lossy(&check.stderr)
    );
}

/// A serial robot's kinematic errors hold 4R + 2P + 6 independent parameters when the full
/// pose is measured and 4R + 2P + 3 from positions of a tool point off the last joint's axis
/// (Everhart's count, also Zhuang & Roth's completeness condition): the default model, complete
/// and pruned, has exactly that many coefficients.
#[test]
fn the_default_model_is_complete_and_minimal() {
    let import = |file: &str, observe| {
        let options = Options {
            observe,
            ..Options::default()
        };
        if file == "mixed.urdf" {
            urdf::import(&mixed_urdf(), Path::new(file), &options).unwrap()
        } else {
            urdf::import_file(&repo(file), &options).unwrap()
        }
    };
    for (file, observe, revolute, prismatic, ends) in [
        ("examples/urdf/ur5.urdf", Observe::Pose, 6, 0, 6),
        ("examples/urdf/robot_6axis.urdf", Observe::Pose, 6, 0, 6),
        ("mixed.urdf", Observe::Pose, 4, 2, 6),
        ("mixed.urdf", Observe::Position, 4, 2, 3),
    ] {
        let i = import(file, observe);
        assert_eq!(
            i.coefficients,
            4 * revolute + 2 * prismatic + ends,
            "{file} {observe:?}: {}",
            i.source
        );
    }
    // tool0 lies on the last joint's axis: positions cannot see that joint turn.
    let i = import("examples/urdf/ur5.urdf", Observe::Position);
    assert!(
        i.redundant.iter().any(|t| t == "wrist_3_joint.rz"),
        "{:?}",
        i.redundant
    );
}

/// The robot example passes through URDF: its hand-written URDF imports into a model whose
/// nominal chain is the example's own.
#[test]
fn the_robot_example_round_trips_through_urdf() {
    let example = std::fs::read_to_string(repo("examples/robot_6axis.kin")).unwrap();
    let i =
        urdf::import_file(&repo("examples/urdf/robot_6axis.urdf"), &Options::default()).unwrap();
    assert_eq!(i.tip, "gripper");
    let imported = kin_compiler::compile(&i.source).compiled.unwrap().machine;
    let original = kin_compiler::compile(&example).compiled.unwrap().machine;
    for (a, b) in imported.axes.iter().zip(&original.axes) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.continuous, b.continuous, "{}", a.name);
        assert!((a.range[0] - b.range[0]).abs() < 1e-12 && (a.range[1] - b.range[1]).abs() < 1e-12);
    }
    // The example measures from a workpiece frame 1200 mm out and 300 mm up; the URDF from
    // the base: T_urdf(base → gripper) = S_wr · T_example(wr → tl).
    let s_wr = origin([1.2, 0.0, 0.3], [0.0; 3]);
    let urdf = read_urdf(&std::fs::read_to_string(repo("examples/urdf/robot_6axis.urdf")).unwrap());
    let (dp, dr) = compare(&example, &urdf, "base", "gripper", s_wr, 1000);
    assert!(
        dp <= 1e-9 && dr <= 1e-9,
        "example vs URDF: {dp:e} m, {dr:e} rad"
    );
    let (dp, dr) = compare(&i.source, &urdf, "base", "gripper", identity(), 1000);
    assert!(
        dp <= 1e-9 && dr <= 1e-9,
        "import vs URDF: {dp:e} m, {dr:e} rad\n{}",
        i.source
    );
}

/// Prismatic joints, fixed joints between moving ones, axes along no coordinate axis and
/// negative ones, a continuous joint, rotated origins, and a side branch.
fn mixed_urdf() -> String {
    r#"<?xml version="1.0"?>
<robot name="mixed-bench">
  <link name="floor"/> <link name="column"/> <link name="slide"/> <link name="arm"/>
  <link name="elbow"/> <link name="bracket"/> <link name="wrist"/> <link name="spin"/>
  <link name="quill"/> <link name="probe"/> <link name="camera"/>
  <joint name="mount" type="fixed">
    <parent link="floor"/><child link="column"/>
    <origin xyz="0.1 -0.2 0.05" rpy="0.1 -0.2 0.3"/>
  </joint>
  <joint name="lift" type="prismatic">
    <parent link="column"/><child link="slide"/>
    <origin xyz="0 0 0.4" rpy="0 0 0.5"/>
    <axis xyz="0.6 0 0.8"/>
    <limit lower="-0.1" upper="0.6" effort="1" velocity="1"/>
  </joint>
  <joint name="swing" type="revolute">
    <parent link="slide"/><child link="arm"/>
    <origin xyz="0.3 0.02 0" rpy="1.2 0.4 -0.7"/>
    <axis xyz="1 1 1"/>
    <limit lower="-2" upper="2.5" effort="1" velocity="1"/>
  </joint>
  <joint name="arm-elbow" type="fixed">
    <parent link="arm"/><child link="elbow"/>
    <origin xyz="0.25 0 0.01" rpy="0 1.5707963267948966 0"/>
  </joint>
  <joint name="bend" type="revolute">
    <parent link="elbow"/><child link="bracket"/>
    <origin xyz="0 0.1 0" rpy="-0.3 0 0"/>
    <axis xyz="0 -1 0"/>
    <limit lower="-1.5" upper="1.5" effort="1" velocity="1"/>
  </joint>
  <joint name="roll" type="continuous">
    <parent link="bracket"/><child link="wrist"/>
    <origin xyz="0.05 0.05 0.2" rpy="3.0 -1.5707963267948966 2.0"/>
    <axis xyz="-0.3 0.5 0.2"/>
  </joint>
  <joint name="spindle" type="revolute">
    <parent link="wrist"/><child link="spin"/>
    <origin xyz="0 0 0.07"/>
    <axis xyz="1 0 0"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="plunge" type="prismatic">
    <parent link="spin"/><child link="quill"/>
    <origin xyz="0.01 0 0.02" rpy="0 0 3.141592653589793"/>
    <axis xyz="0 0 -1"/>
    <limit lower="0" upper="0.05" effort="1" velocity="1"/>
  </joint>
  <joint name="tip" type="fixed">
    <parent link="quill"/><child link="probe"/>
    <origin xyz="0 0.003 0.12" rpy="0.01 0.02 0.03"/>
  </joint>
  <joint name="camera_mount" type="fixed">
    <parent link="arm"/><child link="camera"/>
    <origin xyz="0 0 0.1"/>
  </joint>
</robot>
"#
    .to_string()
}

#[test]
fn prismatic_fixed_and_skew_axes_import_exactly() {
    let text = mixed_urdf();
    let urdf = read_urdf(&text);
    let i = urdf::import(&text, Path::new("mixed.urdf"), &Options::default()).unwrap();
    // The probe has six moving joints above it, the camera two.
    assert_eq!((i.base.as_str(), i.tip.as_str()), ("floor", "probe"));
    assert_eq!(i.fixed, 3);
    let (dp, dr) = compare(&i.source, &urdf, "floor", "probe", identity(), 2000);
    assert!(
        dp <= 1e-9 && dr <= 1e-9,
        "{dp:e} m, {dr:e} rad\n{}",
        i.source
    );
    assert!(
        i.source.contains("axis bend revolute about -y range"),
        "{}",
        i.source
    );
    assert!(
        i.source
            .contains("axis plunge prismatic along -z range 0 mm .. 50 mm"),
        "{}",
        i.source
    );
    assert!(
        i.source
            .contains("axis lift prismatic along z range -100 mm .. 600 mm"),
        "{}",
        i.source
    );

    // A sub-chain chosen with --base and --tip.
    let options = Options {
        base: Some("slide".into()),
        tip: Some("camera".into()),
        ..Options::default()
    };
    let i = urdf::import(&text, Path::new("mixed.urdf"), &options).unwrap();
    assert_eq!(i.joints, ["swing"]);
    let (dp, dr) = compare(&i.source, &urdf, "slide", "camera", identity(), 200);
    assert!(
        dp <= 1e-9 && dr <= 1e-9,
        "{dp:e} m, {dr:e} rad\n{}",
        i.source
    );
}

/// A URDF with one joint `j` of the given type and inner XML between `base` and `tip`.
fn one_joint(kind: &str, inner: &str) -> String {
    format!(
        "<robot name=\"r\">\n  <link name=\"base\"/>\n  <link name=\"tip\"/>\n  <joint name=\"j\" type=\"{kind}\">\n    <parent link=\"base\"/><child link=\"tip\"/>\n{inner}\n  </joint>\n</robot>\n"
    )
}

/// Every refusal, with its located message, exactly.
#[test]
fn bad_files_are_refused_with_located_messages() {
    let limit = "    <limit lower=\"-1\" upper=\"1\"/>";
    let cases: Vec<(String, Options, &str)> = vec![
        (
            "<robot name=\"r\"><link name=\"a\">".into(),
            Options::default(),
            "bad.urdf:1:1: not well-formed XML: the root node was opened but never closed",
        ),
        (
            "<model name=\"r\"/>".into(),
            Options::default(),
            "bad.urdf:1:1: the root element is `<model>`; a URDF file holds one `<robot>`",
        ),
        (
            one_joint("floating", ""),
            Options::default(),
            "bad.urdf:4:3: joint `j` (floating) on the chain from `base` to `tip` moves in six degrees of freedom; a kin axis is one (prismatic or revolute)",
        ),
        (
            one_joint("planar", "    <axis xyz=\"0 0 1\"/>"),
            Options::default(),
            "bad.urdf:4:3: joint `j` (planar) on the chain from `base` to `tip` moves in a plane, two degrees of freedom; a kin axis is one (prismatic or revolute)",
        ),
        (
            one_joint("revolute", &format!("{limit}\n    <mimic joint=\"other\" multiplier=\"2\"/>")),
            Options::default(),
            "bad.urdf:4:3: joint `j` (revolute) on the chain from `base` to `tip` mimics joint `other`: its position follows another joint's, and a kin axis is an independent degree of freedom",
        ),
        (
            one_joint("revolute", ""),
            Options::default(),
            "bad.urdf:4:3: joint `j` (revolute) has no `<limit lower=\"…\" upper=\"…\"/>`, which URDF requires for revolute and prismatic joints",
        ),
        (
            one_joint("prismatic", "    <limit lower=\"0.5\" upper=\"0.5\"/>"),
            Options::default(),
            "bad.urdf:6:5: joint `j` has limits lower 0.5 m, upper 0.5 m: kin needs lower < upper (a joint that cannot move is `fixed`)",
        ),
        (
            one_joint("revolute", &format!("    <origin xyz=\"0 0\"/>\n{limit}")),
            Options::default(),
            "bad.urdf:6:18: `xyz=\"0 0\"` has 2 values: URDF expects three numbers separated by spaces",
        ),
        (
            one_joint("revolute", &format!("    <origin rpy=\"0 nan 0\"/>\n{limit}")),
            Options::default(),
            "bad.urdf:6:18: `rpy=\"0 nan 0\"` has `nan`, not a finite number: URDF expects three numbers separated by spaces",
        ),
        (
            one_joint("revolute", &format!("    <axis xyz=\"0 0 0\"/>\n{limit}")),
            Options::default(),
            "bad.urdf:6:5: joint `j` has a zero axis: a revolute joint needs a direction",
        ),
        (
            one_joint("hinge", ""),
            Options::default(),
            "bad.urdf:4:25: joint `j` has type `hinge`; URDF's types are revolute, continuous, prismatic, fixed, floating and planar",
        ),
        (
            one_joint("fixed", ""),
            Options::default(),
            "bad.urdf: no joint moves between the base link `base` and the tip link `tip`",
        ),
        (
            "<robot name=\"r\">\n  <link name=\"a\"/>\n  <link name=\"b\"/>\n  <joint name=\"j1\" type=\"continuous\"><parent link=\"a\"/><child link=\"b\"/></joint>\n  <joint name=\"j2\" type=\"continuous\"><parent link=\"b\"/><child link=\"a\"/></joint>\n</robot>".into(),
            Options::default(),
            "bad.urdf:4:3: every link is the child of a joint, so the joints form a closed loop, which kin cannot model (a machine is serial chains)",
        ),
        (
            "<robot name=\"r\">\n  <link name=\"a\"/>\n  <link name=\"b\"/>\n  <link name=\"c\"/>\n  <joint name=\"j1\" type=\"continuous\"><parent link=\"a\"/><child link=\"c\"/></joint>\n  <joint name=\"j2\" type=\"continuous\"><parent link=\"b\"/><child link=\"c\"/></joint>\n</robot>".into(),
            Options::default(),
            "bad.urdf:6:3: link `c` is the child of joint `j1` (line 5) and of joint `j2`: a closed loop, which kin cannot model (a machine is serial chains)",
        ),
        (
            "<robot name=\"r\">\n  <link name=\"a\"/>\n  <joint name=\"j1\" type=\"continuous\"><parent link=\"a\"/><child link=\"b\"/></joint>\n</robot>".into(),
            Options::default(),
            "bad.urdf:3:3: joint `j1` names child link `b`, which is not declared",
        ),
        (
            "<robot name=\"r\">\n  <link name=\"a\"/>\n  <link name=\"a\"/>\n</robot>".into(),
            Options::default(),
            "bad.urdf:3:3: link `a` is declared twice (first at 2:3)",
        ),
        (
            "<robot name=\"r\" xmlns:xacro=\"http://www.ros.org/wiki/xacro\">\n  <xacro:property name=\"d1\" value=\"0.1\"/>\n</robot>".into(),
            Options::default(),
            "bad.urdf:2:3: `xacro:property` is a xacro macro, not URDF: expand the file first (`xacro ROBOT.urdf.xacro > ROBOT.urdf`)",
        ),
        (
            one_joint("revolute", &format!("    <origin xyz=\"0 0 ${{d1}}\"/>\n{limit}")),
            Options::default(),
            "bad.urdf:6:18: `xyz=\"0 0 ${d1}\"` is a xacro expression, not URDF: expand the file first (`xacro ROBOT.urdf.xacro > ROBOT.urdf`)",
        ),
        (
            one_joint("revolute", limit),
            Options {
                tip: Some("flange".into()),
                ..Options::default()
            },
            "bad.urdf: --tip `flange`: the robot has no link of that name",
        ),
        (
            one_joint("revolute", limit),
            Options {
                base: Some("tip".into()),
                tip: Some("base".into()),
                ..Options::default()
            },
            "bad.urdf: --tip `base` is not below the base link `tip`: no chain of joints leads from one to the other",
        ),
        (
            "<robot name=\"r\">\n  <link name=\"a\"/><link name=\"b\"/><link name=\"c\"/>\n  <joint name=\"j1\" type=\"continuous\"><parent link=\"a\"/><child link=\"b\"/></joint>\n  <joint name=\"j2\" type=\"continuous\"><parent link=\"a\"/><child link=\"c\"/></joint>\n</robot>".into(),
            Options::default(),
            "bad.urdf: the tip link is not clear: the leaves `b`, `c` each have 1 moving joints above them; choose one with --tip LINK",
        ),
    ];
    let mut wrong = Vec::new();
    for (text, options, expected) in &cases {
        match urdf::import(text, Path::new("bad.urdf"), options) {
            Ok(i) => wrong.push(format!("accepted:\n{text}\n{}", i.source)),
            Err(e) if e.to_string() != *expected => {
                wrong.push(format!("expected: {expected}\n     got: {e}"))
            }
            Err(_) => {}
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n\n"));
}

#[test]
fn the_command_keeps_its_exit_codes_and_its_input() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.urdf");
    std::fs::write(&bad, one_joint("floating", "")).unwrap();
    let run = kin().args(["import", "urdf"]).arg(&bad).output().unwrap();
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("bad.urdf:4:3: joint `j` (floating)"), "{err}");

    // -o naming the input is refused before anything is read or written.
    let good = dir.path().join("r.urdf");
    let text = one_joint("continuous", "");
    std::fs::write(&good, &text).unwrap();
    let run = kin()
        .args(["import", "urdf"])
        .arg(&good)
        .arg("-o")
        .arg(&good)
        .output()
        .unwrap();
    assert_eq!(run.status.code(), Some(2));
    assert_eq!(std::fs::read_to_string(&good).unwrap(), text);

    let run = kin()
        .args(["import", "urdf"])
        .arg(dir.path().join("missing.urdf"))
        .output()
        .unwrap();
    assert_eq!(run.status.code(), Some(2));
    let run = kin()
        .args(["import", "urdf", "--tip", "nowhere"])
        .arg(&good)
        .output()
        .unwrap();
    assert_eq!(run.status.code(), Some(2));

    // Without -o the model goes to standard output and compiles.
    let run = kin().args(["import", "urdf"]).arg(&good).output().unwrap();
    assert!(run.status.success());
    let model = String::from_utf8(run.stdout).unwrap();
    assert!(kin_compiler::compile(&model).compiled.is_some(), "{model}");
    assert!(String::from_utf8_lossy(&run.stderr).contains("imported robot `r`"));
}

#[test]
fn the_command_has_help_with_examples_and_a_manual_page() {
    let help = kin().args(["import", "urdf", "--help"]).output().unwrap();
    assert!(help.status.success());
    let text = String::from_utf8_lossy(&help.stdout);
    assert!(
        text.contains("Examples:") && text.contains("--tip"),
        "{text}"
    );

    let dir = tempfile::tempdir().unwrap();
    let run = kin().arg("man").arg("-o").arg(dir.path()).output().unwrap();
    assert!(run.status.success(), "{run:?}");
    let page = std::fs::read_to_string(dir.path().join("kin-import-urdf.1")).unwrap();
    assert!(
        page.contains(".TH kin-import-urdf 1") && page.contains("Examples:"),
        "{page}"
    );
}

/// spec/urdf.md's SCARA example is what the importer writes for its URDF.
#[test]
fn the_spec_example_is_the_importers_output() {
    let spec = std::fs::read_to_string(repo("spec/urdf.md")).unwrap();
    let block = |fence: &str| {
        let start = spec.find(fence).unwrap() + fence.len();
        let end = start + spec[start..].find("```").unwrap();
        spec[start..end].to_string()
    };
    let xml = block("```xml\n");
    let kin_text = block("```kin check\n");
    let i = urdf::import(&xml, Path::new("scara.urdf"), &Options::default()).unwrap();
    assert_eq!(i.source, kin_text);
    let (dp, dr) = compare(&i.source, &read_urdf(&xml), "base", "tcp", identity(), 500);
    assert!(dp <= 1e-9 && dr <= 1e-9, "{dp:e} m, {dr:e} rad");
}

/// Damaged files — cut anywhere, a character changed — are refused or imported, never a panic.
#[test]
fn damaged_files_never_panic() {
    let text = std::fs::read_to_string(repo("examples/urdf/ur5.urdf")).unwrap();
    let path = Path::new("damaged.urdf");
    for cut in (0..text.len()).step_by(41) {
        if text.is_char_boundary(cut) {
            let _ = urdf::import(&text[..cut], path, &Options::default());
        }
    }
    for at in (0..text.len()).step_by(97) {
        for c in ['"', '<', '/', '-', '9', ' ', 'e', '>'] {
            if !text.is_char_boundary(at) || !text.is_char_boundary(at + 1) {
                continue;
            }
            let mut damaged = text.clone();
            damaged.replace_range(at..at + 1, &c.to_string());
            let _ = urdf::import(&damaged, path, &Options::default());
        }
    }
}

/// A chain longer than any robot's, and a joint offset that is no length, are refused with
/// what is wrong and where, in moments: not "a bug of kin import" after a minute, nor a
/// 300-digit number.
#[test]
fn chains_and_offsets_beyond_any_robot_are_refused_quickly() {
    let chain = |n: usize, first_x: &str| {
        let links: String = (0..=n).map(|i| format!("<link name=\"l{i}\"/>")).collect();
        let joints: String = (0..n)
            .map(|i| {
                let x = if i == 0 { first_x } else { "0" };
                format!(
                    "<joint name=\"j{i}\" type=\"revolute\"><parent link=\"l{i}\"/><child link=\"l{}\"/>\
                     <origin xyz=\"{x} 0 0.1\" rpy=\"0 0 0\"/><axis xyz=\"0 1 0\"/>\
                     <limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/></joint>",
                    i + 1
                )
            })
            .collect();
        format!("<robot name=\"r\">{links}{joints}</robot>")
    };
    let started = std::time::Instant::now();
    let long = urdf::import(
        &chain(300, "0"),
        Path::new("long.urdf"),
        &Options::default(),
    );
    let e = long.expect_err("refused").to_string();
    assert!(
        e.contains("300 moving joints") && e.contains("at most"),
        "{e}"
    );
    assert!(!e.contains("bug"), "{e}");
    let huge = urdf::import(
        &chain(3, "1e308"),
        Path::new("huge.urdf"),
        &Options::default(),
    );
    let e = huge.expect_err("refused").to_string();
    assert!(e.contains("1e308 m") && e.contains("huge.urdf:1:"), "{e}");
    assert!(started.elapsed().as_secs() < 20, "{:?}", started.elapsed());
}

/// A machine with every kind of step the export folds: moving and fixed elements, a prismatic
/// and a skew revolute axis, a continuous one, a workpiece chain with its own axis, two tools,
/// and a constant error on every frame (translations and rotations), bound in `params`.
const CALIBRATED: &str = "machine calibrated {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis J1 revolute about z range -170 deg .. 170 deg
    axis J2 revolute about (0, 0.6, 0.8) range -120 deg .. 120 deg
    axis S prismatic along x range 0 mm .. 400 mm
    axis J3 revolute about y continuous
    axis C revolute about z range -180 deg .. 180 deg
    tool chain {
        J1 moving
        J2 fixed at (50, 0, 400) mm rot (-90, 10, 0) deg
        S moving at (0, 100, 0) mm rot (0, 0, 30) deg
        J3 moving at (300, 0, 20) mm
        tool probe at (0, 0, 120) mm rot (0, 90, 0) deg
        tool star at (40, 10, 100) mm
    }
    workpiece chain {
        C moving at (900, 100, -50) mm rot (2, -1, 0) deg
        workpiece at (0, 0, 30) mm
    }
    errors {
        J1.tx = const
        J1.rx = const
        J2.ty = const
        J2.rz = const
        S.tz = const
        S.ry = const
        J3.tx = const
        J3.rx = const
        probe.tz = const
        probe.ry = const
        C.ty = const
        C.rx = const
        workpiece.tx = const
        workpiece.rz = const
    }
}
params {
    J1.tx[0] = 120 um
    J1.rx[0] = -300 urad
    J2.ty[0] = -80 um
    J2.rz[0] = 450 urad
    S.tz[0] = 60 um
    S.ry[0] = 200 urad
    J3.tx[0] = -150 um
    J3.rx[0] = 700 urad
    probe.tz[0] = 250 um
    probe.ry[0] = -500 urad
    C.ty[0] = 90 um
    C.rx[0] = -120 urad
    workpiece.tx[0] = -70 um
    workpiece.rz[0] = 330 urad
}";

fn rigid_inverse(t: &M4) -> M4 {
    let mut r = identity();
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] = t[j][i];
        }
    }
    for i in 0..3 {
        r[i][3] = -(0..3).map(|k| t[k][i] * t[k][3]).sum::<f64>();
    }
    r
}

#[test]
fn an_exported_urdf_is_the_calibrated_model_to_1e_9() {
    let compiled = kin_compiler::compile(CALIBRATED);
    let machine = compiled
        .compiled
        .unwrap_or_else(|| panic!("{:#?}", compiled.diagnostics))
        .machine;
    let exported = kin_standards::urdf::export(&machine, "calibrated").unwrap();
    assert_eq!(exported.folded, 14);
    assert!(exported.left_out.is_empty(), "{:?}", exported.left_out);
    let urdf = read_urdf(&exported.text);
    let mut it = kin_model::interp::Interpreter::new(&machine).unwrap();
    let mut errors = kin_model::kinematics::FrameErrors::zeros(&machine);
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let (mut dp, mut dr, mut moved) = (0.0f64, 0.0f64, 0.0f64);
    for n in 0..1000 {
        let tool = n % 2;
        let tool_link = machine.tools[tool].name.clone();
        let qk: Vec<f64> = machine
            .axes
            .iter()
            .map(|a| {
                if a.continuous {
                    rng.uniform(-4.0 * std::f64::consts::PI, 4.0 * std::f64::consts::PI)
                } else {
                    rng.uniform(a.range[0], a.range[1])
                }
            })
            .collect();
        let dirs = vec![1.0; qk.len()];
        let state = kin_model::interp::State {
            q: &qk,
            inputs: &[],
            lags: &[],
            time: 0.0,
            dirs: &dirs,
            tool,
            tool_offset: None,
        };
        it.frame_errors(&state, &machine.beta, &mut errors).unwrap();
        let pose = Pose {
            q: &qk,
            tool,
            tool_offset: None,
        };
        let t = kin_model::exact::actual_transform(&machine, &pose, &errors).unwrap();
        let nominal = kin_model::exact::nominal_transform(&machine, &pose).unwrap();
        let q: HashMap<String, f64> = machine
            .axes
            .iter()
            .zip(&qk)
            .map(|(a, v)| (a.name.clone(), *v))
            .collect();
        let tu = mul(
            &rigid_inverse(&urdf.fk("base", "workpiece", &q)),
            &urdf.fk("base", &tool_link, &q),
        );
        for i in 0..3 {
            dp = dp.max((t[(i, 3)] - tu[i][3]).abs());
            moved = moved.max((t[(i, 3)] - nominal[(i, 3)]).abs());
            for j in 0..3 {
                dr = dr.max((t[(i, j)] - tu[i][j]).abs());
            }
        }
    }
    println!("export: position {dp:.2e} m, rotation {dr:.2e}, errors move the tool {moved:.2e} m");
    // The constant errors move the tool by far more than the tolerance: the comparison sees them.
    assert!(moved > 1e-4, "{moved}");
    assert!(dp < 1e-9, "position differs by {dp} m");
    assert!(dr < 1e-9, "rotation differs by {dr}");
}
