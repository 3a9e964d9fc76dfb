//! URDF import: a robot description (ROS's Unified Robot Description Format) turned into a
//! `.kin` machine with a default error model (`kin import urdf`, spec/urdf.md).
//!
//! A URDF file is a tree of `<link>`s joined by `<joint>`s. Each joint places its child link's
//! frame in its parent link's frame by `<origin xyz rpy>` and moves it by the joint motion about
//! or along `<axis xyz>` (given in the child's frame): the child frame is at
//! `Trans(xyz) · Rz(yaw) · Ry(pitch) · Rx(roll) · J(q)` in the parent's. That is a `.kin`
//! *moving* element (`S_k · J_k`, eq. 2.35) whose shape is the origin, so one serial chain of
//! the tree — from a base link to a tip link — is a tool chain with an empty workpiece chain.
//! Fixed joints fold into the next shape; floating and planar joints, mimic joints and closed
//! loops are refused, located, because a kin axis is one independent degree of freedom.
//!
//! [`import`] does the work on a text; [`import_file`] reads the file first.

mod emit;
mod export;

pub(crate) use export::origin_text;
pub use export::{calibrated, export, Calibrated, CalibratedJoint, ExportError, Exported};

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix4, Vector3};
use thiserror::Error;

use kin_estimate::identify::Observe;

/// What an import reads and writes besides the file itself.
#[derive(Debug, Clone)]
pub struct Options {
    /// The link the chain starts from (the machine's base); the tree's root when `None`.
    pub base: Option<String>,
    /// The link the chain ends at (the tool); the only leaf below the base when `None`, or the
    /// one leaf with the most moving joints above it.
    pub tip: Option<String>,
    /// What the default error model is made identifiable for (`kin check --observe`).
    pub observe: Observe,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            base: None,
            tip: None,
            observe: Observe::Pose,
        }
    }
}

/// The most moving joints an imported chain may have: serial robots have 6 or 7, a
/// positioner a few more; a model of hundreds of axes is a file that is not a robot, whose
/// default error model would take minutes to prune.
pub const MAX_JOINTS: usize = 32;
/// The largest joint offset read, m: no link of a robot is longer (`xyz="1e308 0 0"` is not a
/// length).
const MAX_OFFSET: f64 = 1e4;

/// Why a URDF file cannot be imported.
#[derive(Debug, Error)]
pub enum UrdfError {
    #[error("cannot read `{}`: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A problem in the file, at a line and column (1-based).
    #[error("{}:{line}:{column}: {message}", path.display())]
    Invalid {
        path: PathBuf,
        line: u32,
        column: u32,
        message: String,
    },
    /// `--base` or `--tip` does not fit the file, or the tip must be chosen.
    #[error("{}: {message}", path.display())]
    Chain { path: PathBuf, message: String },
    /// The generated model did not compile or check: a bug of the importer, reported rather
    /// than written.
    #[error("the imported model of `{}` does not compile (a bug of kin import, please report it): {message}", path.display())]
    Internal { path: PathBuf, message: String },
}

impl UrdfError {
    /// Whether the user's options rather than the file are at fault (exit 2 rather than 1).
    pub fn is_usage(&self) -> bool {
        matches!(self, UrdfError::Io { .. } | UrdfError::Chain { .. })
    }
}

/// A `.kin` model imported from a URDF file, and what the import chose.
#[derive(Debug, Clone)]
pub struct Imported {
    /// The `.kin` source.
    pub source: String,
    pub robot: String,
    pub base: String,
    pub tip: String,
    /// Moving joints of the chain, base to tip (URDF names).
    pub joints: Vec<String>,
    /// Fixed joints folded into shapes.
    pub fixed: usize,
    /// Coefficients of the default error model.
    pub coefficients: usize,
    /// Candidate terms left out as redundant for the chosen observation (`J.tz`, …).
    pub redundant: Vec<String>,
}

/// Reads `path` (at most 64 MiB) and imports it.
pub fn import_file(path: &Path, options: &Options) -> Result<Imported, UrdfError> {
    import(&read_text(path)?, path, options)
}

/// The text of a robot description at `path`: at most 64 MiB of UTF-8, a bad byte reported at
/// its line and column.
pub(crate) fn read_text(path: &Path) -> Result<String, UrdfError> {
    use kin_data::bounded_read::{read, BoundedReadError, MAX_TEXT_BYTES};
    let io = |source| UrdfError::Io {
        path: path.to_path_buf(),
        source,
    };
    let bytes = read(path, MAX_TEXT_BYTES).map_err(|e| match e {
        BoundedReadError::Io(source) => io(source),
        BoundedReadError::TooLarge { limit } => io(std::io::Error::other(format!(
            "larger than {} MiB, the most kin reads from a robot description",
            limit >> 20
        ))),
    })?;
    match String::from_utf8(bytes) {
        Ok(text) => Ok(text),
        Err(e) => {
            let bytes = e.as_bytes();
            let valid = bytes
                .get(..e.utf8_error().valid_up_to())
                .unwrap_or_default();
            let line = 1 + valid.iter().filter(|&&b| b == b'\n').count();
            let column = 1 + valid.iter().rev().take_while(|&&b| b != b'\n').count();
            Err(UrdfError::Invalid {
                path: path.to_path_buf(),
                line: u32::try_from(line).unwrap_or(u32::MAX),
                column: u32::try_from(column).unwrap_or(u32::MAX),
                message: "not valid UTF-8".into(),
            })
        }
    }
}

/// Imports the URDF `text`; `path` names it in messages and in the model's header comment.
pub fn import(text: &str, path: &Path, options: &Options) -> Result<Imported, UrdfError> {
    let robot = read_robot(text, path)?;
    let chain = choose_chain(&robot, path, options)?;
    emit::model(&robot, &chain, path, options)
}

// ------------------------------------------------------------------------------- the tree

/// A place in the file, 1-based.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Loc {
    line: u32,
    column: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum JointType {
    Revolute,
    Continuous,
    Prismatic,
    Fixed,
    Floating,
    Planar,
}

impl JointType {
    fn name(self) -> &'static str {
        match self {
            JointType::Revolute => "revolute",
            JointType::Continuous => "continuous",
            JointType::Prismatic => "prismatic",
            JointType::Fixed => "fixed",
            JointType::Floating => "floating",
            JointType::Planar => "planar",
        }
    }
}

#[derive(Debug, Clone)]
struct Joint {
    name: String,
    kind: JointType,
    parent: String,
    child: String,
    /// `<origin>`: the child frame in the parent frame at q = 0.
    origin: Matrix4<f64>,
    /// `<axis xyz>`, normalised, in the child (joint) frame.
    axis: Vector3<f64>,
    /// `<limit lower upper>` in m or rad, when given.
    limit: Option<(f64, f64, Loc)>,
    /// `<mimic joint=…>`: the joint it follows.
    mimic: Option<String>,
    at: Loc,
}

#[derive(Debug, Clone)]
struct Robot {
    name: String,
    at: Loc,
    links: Vec<(String, Loc)>,
    joints: Vec<Joint>,
}

/// A serial chain of the tree: the joints from `base` to `tip`, base first.
#[derive(Debug, Clone)]
struct Chain {
    base: String,
    tip: String,
    joints: Vec<usize>,
}

/// URDF `rpy`: roll about the fixed x axis, then pitch about fixed y, then yaw about fixed z,
/// so `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.
fn rpy_matrix(rpy: [f64; 3]) -> Matrix3<f64> {
    let [r, p, y] = rpy;
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, r.cos(), -r.sin(), 0.0, r.sin(), r.cos());
    let ry = Matrix3::new(p.cos(), 0.0, p.sin(), 0.0, 1.0, 0.0, -p.sin(), 0.0, p.cos());
    let rz = Matrix3::new(y.cos(), -y.sin(), 0.0, y.sin(), y.cos(), 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

fn transform(rotation: &Matrix3<f64>, translation: &Vector3<f64>) -> Matrix4<f64> {
    let mut t = Matrix4::identity();
    t.fixed_view_mut::<3, 3>(0, 0).copy_from(rotation);
    t.fixed_view_mut::<3, 1>(0, 3).copy_from(translation);
    t
}

const XACRO: &str = "http://www.ros.org/wiki/xacro";

struct Reader<'a, 'i> {
    doc: &'a roxmltree::Document<'i>,
    path: &'a Path,
}

impl<'a, 'i> Reader<'a, 'i> {
    fn loc(&self, pos: usize) -> Loc {
        let p = self.doc.text_pos_at(pos);
        Loc {
            line: p.row,
            column: p.col,
        }
    }

    fn at(&self, node: roxmltree::Node<'_, '_>) -> Loc {
        self.loc(node.range().start)
    }

    fn invalid(&self, at: Loc, message: impl Into<String>) -> UrdfError {
        UrdfError::Invalid {
            path: self.path.to_path_buf(),
            line: at.line,
            column: at.column,
            message: message.into(),
        }
    }

    /// A required attribute, with its location.
    fn attribute(
        &self,
        node: roxmltree::Node<'_, '_>,
        name: &str,
        what: &str,
    ) -> Result<(String, Loc), UrdfError> {
        match node.attribute_node(name) {
            Some(a) => Ok((a.value().to_string(), self.loc(a.range_value().start))),
            None => Err(self.invalid(
                self.at(node),
                format!("{what} has no `{name}` attribute, which URDF requires"),
            )),
        }
    }

    /// Three numbers of an attribute (`xyz`, `rpy`), or `default` when it is absent.
    fn triple(
        &self,
        node: roxmltree::Node<'_, '_>,
        name: &str,
        default: [f64; 3],
    ) -> Result<[f64; 3], UrdfError> {
        let Some(a) = node.attribute_node(name) else {
            return Ok(default);
        };
        let at = self.loc(a.range_value().start);
        let words: Vec<&str> = a.value().split_whitespace().collect();
        let bad = |why: String| {
            self.invalid(
                at,
                format!(
                    "`{name}=\"{}\"` {why}: URDF expects three numbers separated by spaces",
                    a.value()
                ),
            )
        };
        if words.len() != 3 {
            return Err(bad(format!("has {} values", words.len())));
        }
        let mut out = [0.0; 3];
        for (o, w) in out.iter_mut().zip(&words) {
            *o = number(w).ok_or_else(|| bad(format!("has `{w}`, not a finite number")))?;
        }
        Ok(out)
    }

    /// An optional numeric attribute.
    fn scalar(&self, node: roxmltree::Node<'_, '_>, name: &str) -> Result<Option<f64>, UrdfError> {
        let Some(a) = node.attribute_node(name) else {
            return Ok(None);
        };
        match number(a.value().trim()) {
            Some(v) => Ok(Some(v)),
            None => Err(self.invalid(
                self.loc(a.range_value().start),
                format!("`{name}=\"{}\"` is not a finite number", a.value()),
            )),
        }
    }
}

/// A decimal number as URDF writes it (`-0.425`, `1e-3`); `inf` and `nan` are refused.
fn number(word: &str) -> Option<f64> {
    let looks_numeric = word
        .bytes()
        .all(|b| b.is_ascii_digit() || matches!(b, b'+' | b'-' | b'.' | b'e' | b'E'));
    let v: f64 = word.parse().ok()?;
    (looks_numeric && v.is_finite()).then_some(v)
}

fn first_child<'a, 'i>(
    node: roxmltree::Node<'a, 'i>,
    name: &str,
) -> Option<roxmltree::Node<'a, 'i>> {
    node.children()
        .find(|c| c.is_element() && c.tag_name().name() == name)
}

fn read_robot(text: &str, path: &Path) -> Result<Robot, UrdfError> {
    let doc = roxmltree::Document::parse(text).map_err(|e| {
        let p = e.pos();
        UrdfError::Invalid {
            path: path.to_path_buf(),
            line: p.row,
            column: p.col,
            message: format!("not well-formed XML: {e}"),
        }
    })?;
    let r = Reader { doc: &doc, path };
    let root = doc.root_element();
    // A xacro file is a program that writes URDF: its macros and `${…}` are not URDF.
    for node in doc.descendants() {
        if node.is_element() && node.tag_name().namespace() == Some(XACRO) {
            return Err(r.invalid(
                r.at(node),
                format!(
                    "`xacro:{}` is a xacro macro, not URDF: expand the file first \
                     (`xacro ROBOT.urdf.xacro > ROBOT.urdf`)",
                    node.tag_name().name()
                ),
            ));
        }
        for a in node.attributes() {
            if a.value().contains("${") || a.value().contains("$(") {
                return Err(r.invalid(
                    r.loc(a.range_value().start),
                    format!(
                        "`{}=\"{}\"` is a xacro expression, not URDF: expand the file first \
                         (`xacro ROBOT.urdf.xacro > ROBOT.urdf`)",
                        a.name(),
                        a.value()
                    ),
                ));
            }
        }
    }
    if root.tag_name().name() != "robot" {
        return Err(r.invalid(
            r.at(root),
            format!(
                "the root element is `<{}>`; a URDF file holds one `<robot>`",
                root.tag_name().name()
            ),
        ));
    }
    let name = root.attribute("name").unwrap_or("robot").to_string();
    let mut robot = Robot {
        name,
        at: r.at(root),
        links: Vec::new(),
        joints: Vec::new(),
    };
    let mut links: HashMap<String, Loc> = HashMap::new();
    let mut joints: HashMap<String, Loc> = HashMap::new();
    for node in root.children().filter(|n| n.is_element()) {
        match node.tag_name().name() {
            "link" => {
                let (name, _) = r.attribute(node, "name", "`<link>`")?;
                let at = r.at(node);
                if let Some(first) = links.get(&name) {
                    return Err(r.invalid(
                        at,
                        format!(
                            "link `{name}` is declared twice (first at {}:{})",
                            first.line, first.column
                        ),
                    ));
                }
                links.insert(name.clone(), at);
                robot.links.push((name, at));
            }
            "joint" => {
                let joint = read_joint(&r, node)?;
                if let Some(first) = joints.get(&joint.name) {
                    return Err(r.invalid(
                        joint.at,
                        format!(
                            "joint `{}` is declared twice (first at {}:{})",
                            joint.name, first.line, first.column
                        ),
                    ));
                }
                joints.insert(joint.name.clone(), joint.at);
                robot.joints.push(joint);
            }
            // Materials, transmissions, Gazebo extensions: nothing kinematic.
            _ => {}
        }
    }
    check_tree(&r, &robot, &links)?;
    Ok(robot)
}

fn read_joint(r: &Reader<'_, '_>, node: roxmltree::Node<'_, '_>) -> Result<Joint, UrdfError> {
    let at = r.at(node);
    let (name, _) = r.attribute(node, "name", "`<joint>`")?;
    let what = format!("joint `{name}`");
    let (kind, kind_at) = r.attribute(node, "type", &what)?;
    let kind = match kind.as_str() {
        "revolute" => JointType::Revolute,
        "continuous" => JointType::Continuous,
        "prismatic" => JointType::Prismatic,
        "fixed" => JointType::Fixed,
        "floating" => JointType::Floating,
        "planar" => JointType::Planar,
        other => {
            return Err(r.invalid(
                kind_at,
                format!(
                    "joint `{name}` has type `{other}`; URDF's types are revolute, continuous, \
                     prismatic, fixed, floating and planar"
                ),
            ))
        }
    };
    let link_of = |element: &str| -> Result<String, UrdfError> {
        let Some(n) = first_child(node, element) else {
            return Err(r.invalid(
                at,
                format!("joint `{name}` has no `<{element} link=\"…\"/>`, which URDF requires"),
            ));
        };
        Ok(
            r.attribute(n, "link", &format!("the `<{element}>` of joint `{name}`"))?
                .0,
        )
    };
    let parent = link_of("parent")?;
    let child = link_of("child")?;
    let origin = match first_child(node, "origin") {
        Some(o) => {
            let xyz = r.triple(o, "xyz", [0.0; 3])?;
            if let Some(big) = xyz.iter().find(|v| v.abs() > MAX_OFFSET) {
                let at = o
                    .attribute_node("xyz")
                    .map_or(r.at(o), |a| r.loc(a.range_value().start));
                return Err(r.invalid(
                    at,
                    format!(
                        "origin `xyz` has {big:e} m: a link of a robot is not longer than {MAX_OFFSET} m (URDF lengths are in metres)"
                    ),
                ));
            }
            let rpy = r.triple(o, "rpy", [0.0; 3])?;
            transform(&rpy_matrix(rpy), &Vector3::from(xyz))
        }
        None => Matrix4::identity(),
    };
    let (axis, axis_at) = match first_child(node, "axis") {
        Some(a) => (Vector3::from(r.triple(a, "xyz", [1.0, 0.0, 0.0])?), r.at(a)),
        None => (Vector3::x(), at),
    };
    let moves = matches!(
        kind,
        JointType::Revolute | JointType::Continuous | JointType::Prismatic
    );
    let norm = axis.norm();
    if moves && !(norm > 1e-12) {
        return Err(r.invalid(
            axis_at,
            format!(
                "joint `{name}` has a zero axis: a {} joint needs a direction",
                kind.name()
            ),
        ));
    }
    let axis = if moves { axis / norm } else { axis };
    let limit = match first_child(node, "limit") {
        Some(l) => {
            let lower = r.scalar(l, "lower")?.unwrap_or(0.0);
            let upper = r.scalar(l, "upper")?.unwrap_or(0.0);
            Some((lower, upper, r.at(l)))
        }
        None => None,
    };
    let mimic = match first_child(node, "mimic") {
        Some(m) => Some(
            r.attribute(m, "joint", &format!("the `<mimic>` of joint `{name}`"))?
                .0,
        ),
        None => None,
    };
    Ok(Joint {
        name,
        kind,
        parent,
        child,
        origin,
        axis,
        limit,
        mimic,
        at,
    })
}

/// Every joint names declared links, every link has at most one parent joint, and the links
/// form one tree.
fn check_tree(
    r: &Reader<'_, '_>,
    robot: &Robot,
    links: &HashMap<String, Loc>,
) -> Result<(), UrdfError> {
    let mut parent_of: HashMap<&str, &Joint> = HashMap::new();
    for j in &robot.joints {
        for (role, link) in [("parent", &j.parent), ("child", &j.child)] {
            if !links.contains_key(link) {
                return Err(r.invalid(
                    j.at,
                    format!(
                        "joint `{}` names {role} link `{link}`, which is not declared",
                        j.name
                    ),
                ));
            }
        }
        if j.parent == j.child {
            return Err(r.invalid(
                j.at,
                format!(
                    "joint `{}` joins link `{}` to itself: a closed loop, which kin cannot model \
                     (a machine is serial chains)",
                    j.name, j.parent
                ),
            ));
        }
        if let Some(first) = parent_of.insert(&j.child, j) {
            return Err(r.invalid(
                j.at,
                format!(
                    "link `{}` is the child of joint `{}` (line {}) and of joint `{}`: a closed \
                     loop, which kin cannot model (a machine is serial chains)",
                    j.child, first.name, first.at.line, j.name
                ),
            ));
        }
    }
    let roots: Vec<&str> = robot
        .links
        .iter()
        .map(|(n, _)| n.as_str())
        .filter(|n| !parent_of.contains_key(n))
        .collect();
    match roots.as_slice() {
        [] if robot.links.is_empty() => {
            return Err(r.invalid(robot.at, "the robot has no `<link>`"));
        }
        [_] => {}
        [] => {
            // Every link has a parent: following parents never ends.
            let j = robot.joints.first().map_or(robot.at, |j| j.at);
            return Err(r.invalid(
                j,
                "every link is the child of a joint, so the joints form a closed loop, which \
                 kin cannot model (a machine is serial chains)",
            ));
        }
        [a, b, ..] => {
            return Err(r.invalid(
                robot.at,
                format!(
                    "the links do not form one tree: `{a}` and `{b}` are both roots (no joint \
                     has them as its child)"
                ),
            ));
        }
    }
    // One root and at most one parent per link: a link that does not lead up to the root
    // is on a loop.
    for j in &robot.joints {
        let mut link = j.child.as_str();
        let mut steps = 0;
        while let Some(p) = parent_of.get(link) {
            link = &p.parent;
            steps += 1;
            if steps > robot.joints.len() {
                return Err(r.invalid(
                    j.at,
                    format!(
                        "joint `{}` is on a closed loop of joints, which kin cannot model (a \
                         machine is serial chains)",
                        j.name
                    ),
                ));
            }
        }
    }
    Ok(())
}

// ------------------------------------------------------------------------------ the chain

fn is_moving(kind: JointType) -> bool {
    !matches!(kind, JointType::Fixed)
}

fn choose_chain(robot: &Robot, path: &Path, options: &Options) -> Result<Chain, UrdfError> {
    let chain_error = |message: String| UrdfError::Chain {
        path: path.to_path_buf(),
        message,
    };
    let parent_of: HashMap<&str, usize> = robot
        .joints
        .iter()
        .enumerate()
        .map(|(i, j)| (j.child.as_str(), i))
        .collect();
    let exists = |name: &str| robot.links.iter().any(|(n, _)| n == name);
    let root = robot
        .links
        .iter()
        .map(|(n, _)| n.as_str())
        .find(|n| !parent_of.contains_key(n))
        .unwrap_or_default();
    let base = match &options.base {
        Some(b) if !exists(b) => {
            return Err(chain_error(format!(
                "--base `{b}`: the robot has no link of that name (its root link is `{root}`)"
            )))
        }
        Some(b) => b.as_str(),
        None => root,
    };
    // The joints from `base` down to `link`, base first, or None when `link` is not below it.
    let path_to = |link: &str| -> Option<Vec<usize>> {
        let mut joints = Vec::new();
        let mut at = link;
        while at != base {
            let &j = parent_of.get(at)?;
            joints.push(j);
            at = robot.joints.get(j).map_or(base, |j| j.parent.as_str());
        }
        joints.reverse();
        Some(joints)
    };
    let moving = |joints: &[usize]| {
        joints
            .iter()
            .filter(|&&j| robot.joints.get(j).is_some_and(|j| is_moving(j.kind)))
            .count()
    };
    let tip = match &options.tip {
        Some(t) if !exists(t) => {
            return Err(chain_error(format!(
                "--tip `{t}`: the robot has no link of that name"
            )))
        }
        Some(t) => t.clone(),
        None => {
            let has_child: std::collections::HashSet<&str> =
                robot.joints.iter().map(|j| j.parent.as_str()).collect();
            let leaves: Vec<(&str, usize)> = robot
                .links
                .iter()
                .map(|(n, _)| n.as_str())
                .filter(|n| !has_child.contains(n))
                .filter_map(|n| path_to(n).map(|p| (n, moving(&p))))
                .collect();
            let most = leaves.iter().map(|l| l.1).max().unwrap_or(0);
            let best: Vec<&str> = leaves.iter().filter(|l| l.1 == most).map(|l| l.0).collect();
            match best.as_slice() {
                [one] => one.to_string(),
                _ => {
                    return Err(chain_error(format!(
                        "the tip link is not clear: the leaves {} each have {most} moving \
                         joints above them; choose one with --tip LINK",
                        best.iter()
                            .map(|l| format!("`{l}`"))
                            .collect::<Vec<_>>()
                            .join(", ")
                    )))
                }
            }
        }
    };
    let Some(joints) = path_to(&tip) else {
        return Err(chain_error(format!(
            "--tip `{tip}` is not below the base link `{base}`: no chain of joints leads from \
             one to the other"
        )));
    };
    for &j in &joints {
        let Some(joint) = robot.joints.get(j) else {
            continue;
        };
        let refuse = |why: &str| {
            Err(UrdfError::Invalid {
                path: path.to_path_buf(),
                line: joint.at.line,
                column: joint.at.column,
                message: format!(
                    "joint `{}` ({}) on the chain from `{base}` to `{tip}` {why}",
                    joint.name,
                    joint.kind.name()
                ),
            })
        };
        match joint.kind {
            JointType::Floating => {
                return refuse(
                    "moves in six degrees of freedom; a kin axis is one (prismatic or revolute)",
                )
            }
            JointType::Planar => {
                return refuse(
                    "moves in a plane, two degrees of freedom; a kin axis is one (prismatic or \
                     revolute)",
                )
            }
            _ => {}
        }
        if let (Some(m), true) = (&joint.mimic, is_moving(joint.kind)) {
            return refuse(&format!(
                "mimics joint `{m}`: its position follows another joint's, and a kin axis is \
                 an independent degree of freedom"
            ));
        }
    }
    if moving(&joints) == 0 {
        return Err(chain_error(format!(
            "no joint moves between the base link `{base}` and the tip link `{tip}`"
        )));
    }
    if moving(&joints) > MAX_JOINTS {
        return Err(chain_error(format!(
            "the chain from `{base}` to `{tip}` has {} moving joints; kin imports serial chains of at most {MAX_JOINTS} (choose a shorter chain with --base and --tip)",
            moving(&joints)
        )));
    }
    Ok(Chain {
        base: base.to_string(),
        tip,
        joints,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rpy_is_fixed_axis_roll_then_pitch_then_yaw() {
        // Roll 90° takes y to z; a yaw of 90° after it (about the fixed z) takes x to y.
        let r = rpy_matrix([
            std::f64::consts::FRAC_PI_2,
            0.0,
            std::f64::consts::FRAC_PI_2,
        ]);
        let y_to = r * Vector3::y();
        let x_to = r * Vector3::x();
        assert!((y_to - Vector3::z()).norm() < 1e-15, "{y_to}");
        assert!((x_to - Vector3::y()).norm() < 1e-15, "{x_to}");
        // A pitch of 90° takes z to x.
        let p = rpy_matrix([0.0, std::f64::consts::FRAC_PI_2, 0.0]);
        assert!((p * Vector3::z() - Vector3::x()).norm() < 1e-15);
    }

    #[test]
    fn numbers_are_finite_decimals() {
        assert_eq!(number("-0.425"), Some(-0.425));
        assert_eq!(number("1e-3"), Some(1e-3));
        assert_eq!(number("inf"), None);
        assert_eq!(number("NaN"), None);
        assert_eq!(number("1e999"), None);
        assert_eq!(number("0x10"), None);
    }
}
