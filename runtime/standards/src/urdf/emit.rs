//! The `.kin` text of an imported chain, and its default error model.
//!
//! Frames. URDF's chain multiplies out to `A₁ J₁(q₁) A₂ J₂(q₂) … Aₙ Jₙ(qₙ) A_tip`, where `A_k`
//! is joint k's origin preceded by the origins of the fixed joints since the previous moving
//! joint, and `J_k` turns about (or slides along) the unit axis `u_k` in the child frame. A kin
//! chain of moving elements multiplies out to `S₁ J₁ S₂ J₂ … Sₙ Jₙ S_tl` (spec/kinematics.md),
//! so `S_k = A_k`, `S_tl = A_tip` and the kin frames are the URDF child-link frames — when `u_k`
//! is a coordinate axis (`about ±x|±y|±z`). Otherwise the frame is turned by a constant rotation
//! `Q_k` with `Q_k e_z = u_k`, since `Rot(u, q) = Q Rot_z(q) Qᵀ` (and likewise for a slide):
//! `S_k = Q_{k−1}ᵀ A_k Q_k`, `S_tl = Q_nᵀ A_tip`, and the joint is `about z`. Its zero offset is
//! then one component (`rz`), as for every other joint.
//!
//! Shapes are written `at (…) mm rot (rx, ry, rz) deg`, `S = Trans · Rot_x · Rot_y · Rot_z`, so
//! each rotation is split into those three angles ([`xyz_angles`]).

use std::collections::HashSet;
use std::fmt::Write as _;
use std::path::Path;

use kin_compiler::ir::{Component, FrameRef};
use kin_compiler::syntax::KEYWORDS;
use nalgebra::{Matrix3, Matrix4, Rotation3, Vector3};

use super::{is_moving, Chain, Imported, JointType, Options, Robot, UrdfError};
use kin_estimate::identify::{self, Column, Observe};

/// The seed of `kin check`'s sampled identifiability analysis: the model is pruned on the same
/// poses `kin check` will look at (structural redundancy does not depend on them).
const CHECK_SEED: u64 = 0x6b696e;

/// Millimetres to 1e-12 m and degrees to 1e-10° (2e-12 rad): far below the 1e-9 at which an
/// imported chain is promised to agree with its URDF.
const MM_DECIMALS: usize = 9;
const DEG_DECIMALS: usize = 10;

/// A joint direction in its kin frame.
#[derive(Debug, Clone, Copy)]
enum Direction {
    /// `±x|±y|±z`: the URDF frame kept.
    Coordinate { index: usize, negative: bool },
    /// The frame turned so that the URDF axis (given here, in the URDF frame) is its z.
    Turned(Vector3<f64>),
}

impl Direction {
    /// The frame component the joint moves in.
    fn index(self) -> usize {
        match self {
            Direction::Coordinate { index, .. } => index,
            Direction::Turned(_) => 2,
        }
    }
}

#[derive(Debug, Clone)]
enum Range {
    Limits(f64, f64),
    Continuous,
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    urdf: String,
    parent: String,
    child: String,
    prismatic: bool,
    range: Range,
    direction: Direction,
    shape: Matrix4<f64>,
    folded: Vec<String>,
}

/// The frame of a candidate term.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Frame {
    Joint(usize),
    Tool,
    /// The workpiece reference `wr`, here the base: where the first joint stands in it.
    Workpiece,
}

/// A candidate term of the default model: a frame and its component 0..6.
type Term = (Frame, usize);

const COMPONENTS: [&str; 6] = ["tx", "ty", "tz", "rx", "ry", "rz"];

fn component_index(c: Component) -> usize {
    match c {
        Component::Tx => 0,
        Component::Ty => 1,
        Component::Tz => 2,
        Component::Rx => 3,
        Component::Ry => 4,
        Component::Rz => 5,
    }
}

pub(super) fn model(
    robot: &Robot,
    chain: &Chain,
    path: &Path,
    options: &Options,
) -> Result<Imported, UrdfError> {
    let mut names = Names::default();
    let machine = names.claim(&robot.name, "robot");
    let (elements, tool_shape, tool_folded) = elements(robot, chain, path, &mut names)?;
    let tool = names.claim(&chain.tip, "tip");

    // Candidates, in the order in which the identifiability analysis keeps the first of terms
    // it cannot tell apart (the text declares them in this order): every joint's zero offset;
    // the tool frame's six (the tool centre point); per joint the constant errors across its
    // axis (the link's lengths and twists) and the last component along or about it; the
    // base's six (where the first joint stands in the base frame).
    let mut candidates: Vec<Term> = Vec::new();
    candidates.extend(
        elements
            .iter()
            .enumerate()
            .map(|(k, e)| (Frame::Joint(k), zero_offset(e))),
    );
    candidates.extend((0..6).map(|c| (Frame::Tool, c)));
    for (k, e) in elements.iter().enumerate() {
        let a = e.direction.index();
        let last = if e.prismatic { a + 3 } else { a };
        let across: Vec<usize> = (0..3).filter(|&i| i != a).collect();
        candidates.extend(across.iter().map(|&i| (Frame::Joint(k), i)));
        candidates.extend(across.iter().map(|&i| (Frame::Joint(k), i + 3)));
        candidates.push((Frame::Joint(k), last));
    }
    candidates.extend((0..6).map(|c| (Frame::Workpiece, c)));

    let text = |keep: &[Term], redundant: &[Term]| {
        source(&Source {
            file: path,
            robot,
            chain,
            machine: &machine,
            tool: &tool,
            elements: &elements,
            tool_shape: &tool_shape,
            tool_folded: &tool_folded,
            keep,
            redundant,
            observe: options.observe,
        })
    };
    let internal = |message: String| UrdfError::Internal {
        path: path.to_path_buf(),
        message,
    };

    // Every candidate, then the dependent ones left out: in column order, a dependent column
    // is a combination of earlier independent ones, so what remains has full rank.
    let all = text(&candidates, &[]);
    let dependent = dependencies(&all, options.observe).map_err(&internal)?;
    let redundant: Vec<Term> = dependent
        .iter()
        .map(|&(frame, c)| (frame, c))
        .filter(|t| candidates.contains(t))
        .collect();
    let keep: Vec<Term> = candidates
        .iter()
        .copied()
        .filter(|t| !redundant.contains(t))
        .collect();
    let source = text(&keep, &redundant);
    let left = dependencies(&source, options.observe).map_err(&internal)?;
    if !left.is_empty() {
        return Err(internal(format!(
            "{} terms are still redundant after pruning",
            left.len()
        )));
    }
    let term_name = |(frame, c): Term| {
        let frame = match frame {
            Frame::Joint(k) => elements.get(k).map_or("?", |e| e.name.as_str()),
            Frame::Tool => tool.as_str(),
            Frame::Workpiece => "workpiece",
        };
        format!("{frame}.{}", COMPONENTS.get(c).copied().unwrap_or("?"))
    };
    Ok(Imported {
        source,
        robot: robot.name.clone(),
        base: chain.base.clone(),
        tip: chain.tip.clone(),
        joints: elements.iter().map(|e| e.urdf.clone()).collect(),
        fixed: chain
            .joints
            .iter()
            .filter(|&&j| robot.joints.get(j).is_some_and(|j| !is_moving(j.kind)))
            .count(),
        coefficients: keep.len(),
        redundant: redundant.into_iter().map(term_name).collect(),
    })
}

/// The component of a joint's own motion: the rotation about its axis (revolute) or the
/// translation along it (prismatic).
fn zero_offset(e: &Element) -> usize {
    let a = e.direction.index();
    if e.prismatic {
        a
    } else {
        a + 3
    }
}

/// Compiles `source` and names the terms its identifiability analysis finds dependent on
/// earlier ones (or invisible), as `(element, component)`.
fn dependencies(source: &str, observe: Observe) -> Result<Vec<Term>, String> {
    let out = kin_compiler::compile(source);
    let Some(mut compiled) = out.compiled else {
        let messages: Vec<String> = out
            .diagnostics
            .iter()
            .map(|d| format!("{} {}", d.code, d.message))
            .collect();
        return Err(messages.join("; "));
    };
    let m = &mut compiled.machine;
    if m.beta.len() != m.coefficients.len() {
        m.beta = vec![0.0; m.coefficients.len()];
    }
    if m.coefficients.is_empty() {
        return Ok(Vec::new());
    }
    let n = identify::poses_for(m.coefficients.len(), observe);
    let report = identify::sampled_verdicts(
        m,
        observe,
        false,
        n,
        CHECK_SEED,
        kin_model::engine::Engine::Interp,
        identify::Condition::Skip,
    )
    .map_err(|e| e.to_string())?;
    let mut out = Vec::new();
    for d in &report.dependencies {
        let Column::Coefficient(j) = d.column else {
            continue;
        };
        let Some(error) = m.coefficients.get(j).and_then(|c| m.errors.get(c.error)) else {
            continue;
        };
        let frame = match error.frame {
            FrameRef::Tool(k) => Frame::Joint(k),
            FrameRef::ToolEnd(_) => Frame::Tool,
            FrameRef::WorkpieceEnd => Frame::Workpiece,
            FrameRef::Workpiece(_) => continue,
        };
        out.push((frame, component_index(error.component)));
    }
    Ok(out)
}

/// The chain's elements, base first, and the tool's shape and folded joints.
#[allow(clippy::type_complexity)]
fn elements(
    robot: &Robot,
    chain: &Chain,
    path: &Path,
    names: &mut Names,
) -> Result<(Vec<Element>, Matrix4<f64>, Vec<String>), UrdfError> {
    let mut out = Vec::new();
    let mut pending = Matrix4::identity();
    let mut folded = Vec::new();
    // `Q_{k−1}ᵀ` of the previous element, as a 4×4 transform.
    let mut turned_back = Matrix4::identity();
    for j in chain.joints.iter().filter_map(|&j| robot.joints.get(j)) {
        if !is_moving(j.kind) {
            pending *= j.origin;
            folded.push(j.name.clone());
            continue;
        }
        let invalid = |at: super::Loc, message: String| UrdfError::Invalid {
            path: path.to_path_buf(),
            line: at.line,
            column: at.column,
            message,
        };
        let prismatic = j.kind == JointType::Prismatic;
        let range = match (j.kind, j.limit) {
            (JointType::Continuous, _) => Range::Continuous,
            (_, None) => {
                return Err(invalid(
                    j.at,
                    format!(
                        "joint `{}` ({}) has no `<limit lower=\"…\" upper=\"…\"/>`, which URDF \
                         requires for revolute and prismatic joints",
                        j.name,
                        j.kind.name()
                    ),
                ))
            }
            (_, Some((lo, hi, at))) => {
                let unit = if prismatic { "m" } else { "rad" };
                if !(lo < hi) {
                    return Err(invalid(
                        at,
                        format!(
                            "joint `{}` has limits lower {lo} {unit}, upper {hi} {unit}: kin \
                             needs lower < upper (a joint that cannot move is `fixed`)",
                            j.name
                        ),
                    ));
                }
                // kin refuses bounds beyond any machine (spec/semantics.md, Axes).
                let beyond = if prismatic { 1e4 } else { 1e6 };
                if lo.abs() > beyond || hi.abs() > beyond {
                    return Err(invalid(
                        at,
                        format!(
                            "joint `{}` has limits {lo} .. {hi} {unit}, beyond {beyond:e} {unit}, \
                             the largest range kin takes; a revolute joint without limits is \
                             `continuous`",
                            j.name
                        ),
                    ));
                }
                Range::Limits(lo, hi)
            }
        };
        let u = j.axis;
        let coordinate = (0..3).find(|&i| {
            (0..3).all(|k| k == i || u[k].abs() < 1e-12) && (u[i].abs() - 1.0).abs() < 1e-12
        });
        let (direction, q) = match coordinate {
            Some(index) => (
                Direction::Coordinate {
                    index,
                    negative: u[index] < 0.0,
                },
                Matrix3::identity(),
            ),
            // The shortest rotation from z to u; it is undefined only for u = −z, a
            // coordinate axis, for which a half turn about x would do.
            None => {
                let q = Rotation3::rotation_between(&Vector3::z(), &u).map_or_else(
                    || {
                        *Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
                            .matrix()
                    },
                    |r| *r.matrix(),
                );
                (Direction::Turned(u), q)
            }
        };
        let q4 = super::transform(&q, &Vector3::zeros());
        let shape = turned_back * pending * j.origin * q4;
        turned_back = super::transform(&q.transpose(), &Vector3::zeros());
        pending = Matrix4::identity();
        out.push(Element {
            name: names.claim(&j.name, "joint"),
            urdf: j.name.clone(),
            parent: j.parent.clone(),
            child: j.child.clone(),
            prismatic,
            range,
            direction,
            shape,
            folded: std::mem::take(&mut folded),
        });
    }
    Ok((out, turned_back * pending, folded))
}

/// The angles `(a, b, c)` with `R = Rot_x(a) · Rot_y(b) · Rot_z(c)`, the `rot` of a kin shape.
///
/// `R = [[cb·cc, −cb·sc, sb], [·, ·, −sa·cb], [·, ·, ca·cb]]`, so `b` comes from `R₀₂` and
/// `a`, `c` from the last column and first row. At `cb = 0` only `a + c` (or `a − c`) is
/// determined: `c = 0` is taken and `a` read from the second column.
pub(super) fn xyz_angles(r: &Matrix3<f64>) -> [f64; 3] {
    let cb = r[(1, 2)].hypot(r[(2, 2)]);
    let b = r[(0, 2)].atan2(cb);
    if cb > 1e-9 {
        [
            (-r[(1, 2)]).atan2(r[(2, 2)]),
            b,
            (-r[(0, 1)]).atan2(r[(0, 0)]),
        ]
    } else {
        [r[(2, 1)].atan2(r[(1, 1)]), b, 0.0]
    }
}

/// Identifiers for kin: ASCII letters, digits and `_`, not starting with a digit, not a
/// keyword, each used once.
#[derive(Default)]
struct Names {
    taken: HashSet<String>,
}

impl Names {
    fn claim(&mut self, raw: &str, fallback: &str) -> String {
        let mut name: String = raw
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        if name.is_empty() {
            name = fallback.to_string();
        }
        if name.starts_with(|c: char| c.is_ascii_digit()) {
            name.insert(0, '_');
        }
        // `time` is not a keyword but names the time column of a measurement file.
        if KEYWORDS.contains(&name.as_str()) || name == "time" {
            name.push('_');
        }
        let mut unique = name.clone();
        let mut n = 2;
        while self.taken.contains(&unique) {
            unique = format!("{name}_{n}");
            n += 1;
        }
        self.taken.insert(unique.clone());
        unique
    }
}

/// `v` with at most `decimals` decimals, trailing zeros dropped, never `-0`.
fn number(v: f64, decimals: usize) -> String {
    let mut s = format!("{v:.decimals$}");
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    if s == "-0" {
        s = "0".into();
    }
    s
}

/// ` at (…) mm rot (…) deg`, each part only when it is not zero as written.
fn placement(shape: &Matrix4<f64>) -> String {
    let t = shape.fixed_view::<3, 1>(0, 3);
    let r: Matrix3<f64> = shape.fixed_view::<3, 3>(0, 0).into();
    let at: Vec<String> = t.iter().map(|v| number(v * 1e3, MM_DECIMALS)).collect();
    let rot: Vec<String> = xyz_angles(&r)
        .iter()
        .map(|v| number(v.to_degrees(), DEG_DECIMALS))
        .collect();
    let mut s = String::new();
    if at.iter().any(|v| v != "0") {
        let _ = write!(s, " at ({}) mm", at.join(", "));
    }
    if rot.iter().any(|v| v != "0") {
        let _ = write!(s, " rot ({}) deg", rot.join(", "));
    }
    s
}

/// "fixed joint `a`" or "fixed joints `a`, `b`".
fn fixed_joints(names: &[String]) -> String {
    let list = names
        .iter()
        .map(|n| format!("`{n}`"))
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() == 1 {
        format!("fixed joint {list}")
    } else {
        format!("fixed joints {list}")
    }
}

/// A titled group of the errors block and the terms that belong to it.
type Section<'a> = (String, Box<dyn Fn(&Term) -> bool + 'a>);

struct Source<'a> {
    file: &'a Path,
    robot: &'a Robot,
    chain: &'a Chain,
    machine: &'a str,
    tool: &'a str,
    elements: &'a [Element],
    tool_shape: &'a Matrix4<f64>,
    tool_folded: &'a [String],
    keep: &'a [Term],
    redundant: &'a [Term],
    observe: Observe,
}

fn source(s: &Source<'_>) -> String {
    let mut o = String::new();
    let file = s.file.file_name().map_or_else(
        || s.file.display().to_string(),
        |f| f.to_string_lossy().into_owned(),
    );
    let fixed: usize =
        s.elements.iter().map(|e| e.folded.len()).sum::<usize>() + s.tool_folded.len();
    let _ = writeln!(
        o,
        "// Imported by `kin import urdf` from {file} (robot `{}`): the chain of links from\n\
         // `{}` to `{}`, {} moving joints{}.\n\
         // URDF's metres and radians are written in mm and deg. Each element's frame is the URDF\n\
         // frame of the link its joint moves (the joint's child link), unless its comment says\n\
         // the frame is turned to make the joint axis its z. The tool is the tip link; the base\n\
         // link is the machine's base (the workpiece frame).",
        s.robot.name,
        s.chain.base,
        s.chain.tip,
        s.elements.len(),
        if fixed > 0 {
            format!(
                ", {fixed} fixed joint{} folded into the shapes",
                if fixed == 1 { "" } else { "s" }
            )
        } else {
            String::new()
        }
    );
    let _ = writeln!(o, "machine {} {{", s.machine);
    let _ = writeln!(o, "    task position");
    let _ = writeln!(
        o,
        "    units {{ length mm, angle deg, error um, tilt urad }}\n"
    );
    for e in s.elements {
        let kind = if e.prismatic {
            "prismatic along"
        } else {
            "revolute about"
        };
        let dir = match e.direction {
            Direction::Coordinate { index, negative } => {
                format!(
                    "{}{}",
                    if negative { "-" } else { "" },
                    ["x", "y", "z"][index.min(2)]
                )
            }
            Direction::Turned(_) => "z".into(),
        };
        let range = match e.range {
            Range::Continuous => "continuous".to_string(),
            Range::Limits(lo, hi) if e.prismatic => format!(
                "range {} mm .. {} mm",
                number(lo * 1e3, MM_DECIMALS),
                number(hi * 1e3, MM_DECIMALS)
            ),
            Range::Limits(lo, hi) => format!(
                "range {} deg .. {} deg",
                number(lo.to_degrees(), DEG_DECIMALS),
                number(hi.to_degrees(), DEG_DECIMALS)
            ),
        };
        let mut line = format!("    axis {} {kind} {dir} {range}", e.name);
        if e.name != e.urdf {
            let _ = write!(line, "    // URDF joint `{}`", e.urdf);
        }
        let _ = writeln!(o, "{line}");
    }
    let _ = writeln!(o, "\n    tool chain {{");
    for e in s.elements {
        let _ = write!(
            o,
            "        {} moving{}\n            // joint `{}`: `{}` → `{}`",
            e.name,
            placement(&e.shape),
            e.urdf,
            e.parent,
            e.child
        );
        if !e.folded.is_empty() {
            let _ = write!(o, ", after {}", fixed_joints(&e.folded));
        }
        if let Direction::Turned(u) = e.direction {
            let _ = write!(
                o,
                "; frame turned: the URDF axis ({}, {}, {}) is its z",
                number(u.x, 12),
                number(u.y, 12),
                number(u.z, 12)
            );
        }
        let _ = writeln!(o);
    }
    let _ = write!(
        o,
        "        tool {}{}\n            // link `{}`",
        s.tool,
        placement(s.tool_shape),
        s.chain.tip
    );
    if !s.tool_folded.is_empty() {
        let _ = write!(o, ", through {}", fixed_joints(s.tool_folded));
    }
    let _ = writeln!(o, "\n    }}\n");

    let observed = match s.observe {
        Observe::Position => "position measurements (--observe position)",
        Observe::Length => "length measurements (--observe length)",
        Observe::Pose | Observe::Data => "pose measurements",
    };
    let _ = writeln!(
        o,
        "    errors {{\n        // The default model (spec/urdf.md): each joint's zero offset and the constant\n\
         \x20       // errors of its frame (link lengths, twists, offsets), the tool's and the base's,\n\
         \x20       // less the terms that {observed} cannot tell apart from earlier ones."
    );
    // Sections in the candidates' order, so that the text declares them in that order.
    let name_of = |frame: Frame| match frame {
        Frame::Joint(k) => s
            .elements
            .get(k)
            .map_or("?".to_string(), |e| e.name.clone()),
        Frame::Tool => s.tool.to_string(),
        Frame::Workpiece => "workpiece".to_string(),
    };
    let zero = |t: &Term| match t.0 {
        Frame::Joint(k) => s.elements.get(k).is_some_and(|e| zero_offset(e) == t.1),
        _ => false,
    };
    let mut sections: Vec<Section<'_>> = vec![(
        "zero offsets: each joint's error in its own motion (encoder zero)".to_string(),
        Box::new(zero),
    )];
    sections.push((
        format!(
            "tool `{}`: the tool centre point's offset and orientation",
            s.chain.tip
        ),
        Box::new(|t: &Term| t.0 == Frame::Tool),
    ));
    for (k, e) in s.elements.iter().enumerate() {
        sections.push((
            format!(
                "joint `{}`: the link it carries (lengths, twists, offsets)",
                e.urdf
            ),
            Box::new(move |t: &Term| t.0 == Frame::Joint(k) && !zero(t)),
        ));
    }
    sections.push((
        format!(
            "the base `{}`: where the first joint stands in it",
            s.chain.base
        ),
        Box::new(|t: &Term| t.0 == Frame::Workpiece),
    ));
    for (title, belongs) in &sections {
        let _ = writeln!(o, "\n        // {title}");
        for t in s.keep.iter().filter(|t| belongs(t)) {
            let comp = COMPONENTS.get(t.1).copied().unwrap_or("tx");
            let _ = writeln!(o, "        {}.{comp} = const", name_of(t.0));
        }
        let dropped: Vec<String> = s
            .redundant
            .iter()
            .filter(|t| belongs(t))
            .map(|t| {
                format!(
                    "{}.{}",
                    name_of(t.0),
                    COMPONENTS.get(t.1).copied().unwrap_or("?")
                )
            })
            .collect();
        if !dropped.is_empty() {
            let _ = writeln!(
                o,
                "        // left out as redundant: {}",
                dropped.join(", ")
            );
        }
    }
    let _ = writeln!(o, "    }}\n}}");
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rot_x(a: f64) -> Matrix3<f64> {
        Matrix3::new(1.0, 0.0, 0.0, 0.0, a.cos(), -a.sin(), 0.0, a.sin(), a.cos())
    }
    fn rot_y(a: f64) -> Matrix3<f64> {
        Matrix3::new(a.cos(), 0.0, a.sin(), 0.0, 1.0, 0.0, -a.sin(), 0.0, a.cos())
    }
    fn rot_z(a: f64) -> Matrix3<f64> {
        Matrix3::new(a.cos(), -a.sin(), 0.0, a.sin(), a.cos(), 0.0, 0.0, 0.0, 1.0)
    }

    proptest::proptest! {
        #[test]
        fn xyz_angles_rebuild_the_rotation(
            roll in -4.0f64..4.0, pitch in -4.0f64..4.0, yaw in -4.0f64..4.0,
            lock in 0usize..4,
        ) {
            // Some draws sit exactly at or near gimbal lock (pitch ±90°).
            let pitch = match lock {
                0 => std::f64::consts::FRAC_PI_2,
                1 => -std::f64::consts::FRAC_PI_2 + 1e-10,
                _ => pitch,
            };
            let r = super::super::rpy_matrix([roll, pitch, yaw]);
            let [a, b, c] = xyz_angles(&r);
            let back = rot_x(a) * rot_y(b) * rot_z(c);
            proptest::prop_assert!((back - r).norm() < 1e-12, "{} vs {}", back, r);
        }
    }

    #[test]
    fn names_become_kin_identifiers() {
        let mut n = Names::default();
        assert_eq!(n.claim("joint-1", "j"), "joint_1");
        assert_eq!(n.claim("joint_1", "j"), "joint_1_2");
        assert_eq!(n.claim("1st", "j"), "_1st");
        assert_eq!(n.claim("tool", "j"), "tool_");
        assert_eq!(n.claim("", "robot"), "robot");
        assert_eq!(n.claim("épaule", "j"), "_paule");
    }

    #[test]
    fn numbers_are_short_and_never_negative_zero() {
        assert_eq!(number(89.159 + 1e-14, 9), "89.159");
        assert_eq!(number(-1e-14, 9), "0");
        assert_eq!(number(425.0, 9), "425");
        assert_eq!(number(-0.5, 9), "-0.5");
    }
}
