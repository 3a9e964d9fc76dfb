//! The lowered machine: what the interpreter, the exact simulator and the JIT consume.
//!
//! Everything here is in SI base units (m, rad, s, K, N) and carries no source text: names are
//! kept only for reports. A `Machine` is built by `lower` from a checked model and is valid by
//! construction (indices in range, unit axis directions, knots inside ranges), so consumers index
//! without re-checking.

use serde::{Deserialize, Serialize};

use crate::basis::Basis;
use crate::units::Unit;

/// Measuring machines report `indicated − true`, positioning machines `actual − nominal`
/// (spec/kinematics.md; thesis eq. 2.31 / 2.34).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Task {
    Measure,
    Position,
}

impl Task {
    /// The factor applied to an `actual − nominal` error to give the reported error.
    pub fn sign(self) -> f64 {
        match self {
            Task::Measure => -1.0,
            Task::Position => 1.0,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum JointKind {
    Prismatic,
    Revolute,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Axis {
    pub name: String,
    pub kind: JointKind,
    /// Unit vector in the element's own frame.
    pub direction: [f64; 3],
    /// In m or rad. A continuous revolute axis has `[0, 2π]`.
    pub range: [f64; 2],
    pub continuous: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum FrameKind {
    Moving,
    Fixed,
}

/// Nominal location of a frame relative to its predecessor at zero joint positions:
/// `Trans(translation) · Rot_x(rx) · Rot_y(ry) · Rot_z(rz)`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Shape {
    pub translation: [f64; 3],
    pub rotation: [f64; 3],
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Element {
    /// Index into `Machine::axes`.
    pub axis: usize,
    pub frame: FrameKind,
    pub shape: Shape,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Tool {
    pub name: String,
    pub offset: Shape,
}

/// A declared input column (temperature, load, …).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Input {
    pub name: String,
    pub unit: Unit,
    /// Absolute temperatures convert with the 273.15 offset; rises do not.
    pub absolute: bool,
    /// The declared range in SI, if any: where sampled states draw it from.
    #[serde(default)]
    pub range: Option<[f64; 2]>,
}

/// Which of the six parametric errors of a frame (spec/kinematics.md): translations then rotations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Component {
    Tx,
    Ty,
    Tz,
    Rx,
    Ry,
    Rz,
}

impl Component {
    pub const ALL: [Component; 6] = [
        Component::Tx,
        Component::Ty,
        Component::Tz,
        Component::Rx,
        Component::Ry,
        Component::Rz,
    ];
    pub fn index(self) -> usize {
        self as usize
    }
    pub fn is_rotation(self) -> bool {
        self.index() >= 3
    }
    pub fn name(self) -> &'static str {
        ["tx", "ty", "tz", "rx", "ry", "rz"][self.index()]
    }
}

/// What a one-word target stands for: an ISO 230-1 component error (`EXX`, `EBZ`: E, error
/// direction, axis), a VDI 2617 name (`xtx`, `yrz`: axis, translation/rotation, direction), or
/// an ISO 230-1 location or squareness error (`EC0Y`, `EX0C`: E, direction, 0, axis; spec/
/// semantics.md, "Location and squareness"). `Ok(None)` when `name` is none of these for this
/// machine; `Err` when it is a location name the structure cannot carry. The `errors` block and
/// `params` files both resolve through here, so they always agree.
pub fn alias<'a>(name: &str, layout: Layout<'a>) -> Result<Option<Aliased<'a>>, AliasError> {
    let axes = layout.axes;
    let component = |kind: char, dir: char| -> Option<Component> {
        Some(match (kind, dir) {
            ('t', 'x') => Component::Tx,
            ('t', 'y') => Component::Ty,
            ('t', 'z') => Component::Tz,
            ('r', 'x') => Component::Rx,
            ('r', 'y') => Component::Ry,
            ('r', 'z') => Component::Rz,
            _ => return None,
        })
    };
    let plain = |axis: &'a str, component: Component| Aliased {
        axis,
        component,
        sign: 1.0,
    };
    let mut chars = name.chars();
    if let (Some('E'), Some(d)) = (chars.next(), chars.next()) {
        let rest = chars.as_str();
        if let Some(axis) = axes.iter().find(|a| a.name == rest) {
            let c = match d {
                'X' => component('t', 'x'),
                'Y' => component('t', 'y'),
                'Z' => component('t', 'z'),
                'A' => component('r', 'x'),
                'B' => component('r', 'y'),
                'C' => component('r', 'z'),
                _ => None,
            };
            return Ok(c.map(|c| plain(axis.name.as_str(), c)));
        }
        if let Some(found) = location(name, layout)? {
            return Ok(Some(found));
        }
    }
    let chars: Vec<char> = name.chars().collect();
    if let [a, k, d] = chars.as_slice() {
        let Some(axis) = axes
            .iter()
            .find(|ax| ax.name.to_lowercase() == a.to_string())
        else {
            return Ok(None);
        };
        return Ok(component(*k, *d).map(|c| plain(axis.name.as_str(), c)));
    }
    Ok(None)
}

/// The axes and chains an alias is resolved against: a location or squareness name
/// (`EC0Y`, `EX0C`) means a different frame and sign in different structures.
#[derive(Debug, Clone, Copy)]
pub struct Layout<'a> {
    pub axes: &'a [Axis],
    pub tool_chain: &'a [Element],
    pub workpiece_chain: &'a [Element],
}

/// What an alias stands for: `sign ×` the component `component` of the frame of `axis`.
/// A component error (`EXX`, `xtx`) always has sign +1; a location or squareness error may be
/// carried by another axis' frame with sign −1 (spec/semantics.md, "Location and squareness").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aliased<'a> {
    pub axis: &'a str,
    pub component: Component,
    pub sign: f64,
}

/// Why an ISO 230-1 location or squareness name cannot be placed in a machine.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AliasError {
    /// The axis sits in no chain (reported as `E0401` where the chains are resolved).
    #[error("`{axis}` is in no chain")]
    Unplaced { axis: String },
    #[error("`{name}`: a linear axis has no location error, only a direction; `{axis}` moving its line along {dir} changes nothing but a constant offset")]
    LinearLocation {
        name: String,
        axis: String,
        dir: char,
    },
    #[error("`{name}`: `{axis}` moves along {dir}; a rotation about {dir} does not change its direction")]
    ParallelRotation {
        name: String,
        axis: String,
        dir: char,
    },
    #[error(
        "`{name}`: `{axis}` turns about {dir}; shifting its line along {dir} does not move it"
    )]
    AlongLine {
        name: String,
        axis: String,
        dir: char,
    },
    #[error("`{name}`: the frame of `{axis}` is moving, so its constant errors turn with it and cannot place its line")]
    MovingRevolute { name: String, axis: String },
    #[error("`{name}`: no frame of this machine turns `{axis}` about {dir} without turning {others} too")]
    NoSeparatingFrame {
        name: String,
        axis: String,
        dir: char,
        others: String,
    },
    #[error("`{name}`: the axes of `{frame}`'s frame are not aligned with the machine's x, y, z")]
    NotAligned { name: String, frame: String },
}

impl AliasError {
    /// What the user can do about it, for the diagnostic's help line.
    pub fn help(&self) -> String {
        match self {
            AliasError::Unplaced { .. } => String::new(),
            AliasError::LinearLocation { axis, .. } => format!(
                "ISO 230-1 names a linear axis' location by its squareness to the others (`EC0Y`, `EB0Z`, `EA0Z`); a constant offset of `{axis}` is e.g. `{axis}.tx = const`"
            ),
            AliasError::ParallelRotation { axis, .. } => format!(
                "the squareness of `{axis}` is a rotation about one of the two other directions"
            ),
            AliasError::AlongLine { axis, .. } => format!(
                "the location of `{axis}`'s line is given by the two directions across it"
            ),
            AliasError::MovingRevolute { axis, .. } => format!(
                "declare `{axis} fixed` in its chain: a revolute axis' line is placed by the errors of its fixed frame (thesis §2.4)"
            ),
            AliasError::NoSeparatingFrame { axis, .. } => format!(
                "a squareness needs a frame between `{axis}` and the axes it is measured against: give one of them a frame the other does not ride on (`moving` or `fixed`, spec/kinematics.md), or write the rotation on a frame's component directly"
            ),
            AliasError::NotAligned { frame, .. } => format!(
                "write the error on a component of `{frame}` directly (its axes are rotated by `rot` in the chain)"
            ),
        }
    }
}

impl Machine {
    /// The direction of axis `axis` in the base's axes at the home position (every joint at
    /// 0): its own direction turned by the rotations of the shapes up to its element.
    pub fn home_direction(&self, axis: usize) -> Option<[f64; 3]> {
        let a = self.axes.get(axis)?;
        placed(&self.layout())
            .iter()
            .find(|p| p.axis == axis)
            .map(|p| apply(&p.rotation, a.direction))
    }

    pub fn layout(&self) -> Layout<'_> {
        Layout {
            axes: &self.axes,
            tool_chain: &self.tool_chain,
            workpiece_chain: &self.workpiece_chain,
        }
    }

    /// The robot engineer's name of each constant coefficient, as printed beside kin's: on a
    /// machine whose every joint moves about or along its own frame's z (a chain from a
    /// Denavit–Hartenberg table or a URDF import), a constant error of a moving joint's frame
    /// (applied after the joint's motion, so in the axes of the link it moves) is a
    /// Denavit–Hartenberg parameter's error — `rz` the joint offset (δθ, δd for a prismatic
    /// joint), `tz` the link offset (δd), `tx` the link length (δa), `rx` the link twist (δα),
    /// `ry` Hayati's tilt (δβ) — and the tool's and the base's are the tool and base frames.
    /// `None` elsewhere (a Cartesian machine reads its ISO names).
    pub fn robot_names(&self) -> Vec<Option<String>> {
        let mut out = vec![None; self.coefficients.len()];
        let along_z = |d: [f64; 3]| d[0].abs() < 1e-12 && d[1].abs() < 1e-12;
        if self.axes.is_empty() || !self.axes.iter().all(|a| along_z(a.direction)) {
            return out;
        }
        let axes = ["x", "y", "z"];
        for model in &self.errors {
            let c = model.component.index();
            let name = match model.frame {
                FrameRef::Tool(k) | FrameRef::Workpiece(k) => {
                    let chain = match model.frame {
                        FrameRef::Tool(_) => &self.tool_chain,
                        _ => &self.workpiece_chain,
                    };
                    let Some(e) = chain.get(k) else { continue };
                    let Some(axis) = self.axes.get(e.axis) else {
                        continue;
                    };
                    if e.frame != FrameKind::Moving {
                        continue;
                    }
                    let prismatic = axis.kind == JointKind::Prismatic;
                    match (c, prismatic) {
                        (5, false) | (2, true) => "joint offset",
                        (5, true) => "link angle δθ",
                        (2, false) => "link offset δd",
                        (0, _) => "link length δa",
                        (3, _) => "link twist δα",
                        (4, _) => "Hayati tilt δβ",
                        _ => "link offset along y",
                    }
                    .to_string()
                }
                FrameRef::ToolEnd(_) if c < 3 => format!("tool {} offset", axes[c]),
                FrameRef::ToolEnd(_) => format!("tool rotation about {}", axes[c - 3]),
                FrameRef::WorkpieceEnd if c < 3 => format!("base {} offset", axes[c]),
                FrameRef::WorkpieceEnd => format!("base rotation about {}", axes[c - 3]),
            };
            for term in model.terms.iter().filter(|t| t.is_constant()) {
                for j in term.first..term.first + term.coefficients {
                    if let Some(slot) = out.get_mut(j) {
                        *slot = Some(name.clone());
                    }
                }
            }
        }
        out
    }

    /// The ISO 230-1 name of each coefficient, as printed beside kin's: a `const` term of a
    /// component that carries a location or squareness error is that error, with the sign
    /// relating the two (`-EC0Y`: the coefficient is −EC0Y); any other coefficient of an axis'
    /// component is of that component error (`EXX`). `None` for tool and workpiece frames.
    pub fn iso_names(&self) -> Vec<Option<String>> {
        let layout = self.layout();
        let frames = placed(&layout);
        // Every location and squareness name the structure can carry, with what it stands for
        // and whether it is the standard's first choice: a squareness measured against the
        // axis of the lower direction (`EC0Y` against X, not `EC0X` against Y), as ISO 230-1
        // takes X, then Y, as the reference.
        let mut locations: Vec<(String, Aliased<'_>, bool)> = Vec::new();
        for (j, axis) in self.axes.iter().enumerate() {
            let own = frames.iter().find(|p| p.axis == j).map(|p| {
                let d = apply(&p.rotation, axis.direction);
                (0..3)
                    .max_by(|&a, &b| d[a].abs().total_cmp(&d[b].abs()))
                    .unwrap_or(0)
            });
            for (r, d) in ['X', 'Y', 'Z', 'A', 'B', 'C'].into_iter().enumerate() {
                let name = format!("E{d}0{}", axis.name);
                if let Ok(Some(a)) = alias(&name, layout) {
                    let preferred = match (axis.kind, own) {
                        (JointKind::Prismatic, Some(jd)) if r >= 3 && r - 3 != jd => {
                            // The third direction, the reference's: 0 + 1 + 2 = 3.
                            3 - (r - 3) - jd < jd
                        }
                        _ => true,
                    };
                    locations.push((name, a, preferred));
                }
            }
        }
        self.coefficients
            .iter()
            .enumerate()
            .map(|(j, c)| {
                let model = self.errors.get(c.error)?;
                let element = match model.frame {
                    FrameRef::Tool(k) => self.tool_chain.get(k)?,
                    FrameRef::Workpiece(k) => self.workpiece_chain.get(k)?,
                    _ => return None,
                };
                let axis = self.axes.get(element.axis)?;
                let term = model
                    .terms
                    .iter()
                    .find(|t| t.first <= j && j < t.first + t.coefficients)?;
                let constant = term.factors.iter().all(|f| matches!(f.basis, Basis::Const));
                let scale = match term.scale {
                    Scalar::Num(v) if v.abs() == 1.0 => Some(v),
                    _ => None,
                };
                if let (true, Some(scale)) = (constant, scale) {
                    // Prefer a name of the axis itself (`EC0Y` on Y's frame) over one another
                    // axis' squareness places here.
                    let found = locations
                        .iter()
                        .filter(|(_, a, _)| a.axis == axis.name && a.component == model.component)
                        .min_by_key(|(n, _, preferred)| {
                            (!preferred, !n.ends_with(&format!("0{}", axis.name)))
                        });
                    if let Some((name, a, _)) = found {
                        let sign = if a.sign * scale < 0.0 { "-" } else { "" };
                        return Some(format!("{sign}{name}"));
                    }
                }
                let d = ['X', 'Y', 'Z', 'A', 'B', 'C'][model.component.index()];
                Some(format!("E{d}{}", axis.name))
            })
            .collect()
    }
}

/// Whether `name` has the form of an ISO 230-1 location name (`EC0Y`, `EX0C`): `E`, a
/// direction, `0`. Axis names start with a letter, so no component error looks like one.
pub fn is_location(name: &str) -> bool {
    let mut c = name.chars();
    c.next() == Some('E') && c.next().is_some() && c.next() == Some('0')
}

/// The machine direction (x, y, z) an ISO 230-1 error letter refers to: `X Y Z` translations,
/// `A B C` rotations about x, y, z (right-handed).
fn letter(d: char) -> Option<(bool, usize)> {
    Some(match d {
        'X' => (false, 0),
        'Y' => (false, 1),
        'Z' => (false, 2),
        'A' => (true, 0),
        'B' => (true, 1),
        'C' => (true, 2),
        _ => return None,
    })
}

/// `Rot_x(rx) · Rot_y(ry) · Rot_z(rz)` of a shape (spec/kinematics.md, "Elementary transforms").
fn shape_rotation(s: &Shape) -> [[f64; 3]; 3] {
    let [a, b, c] = s.rotation;
    let (sa, ca) = a.sin_cos();
    let (sb, cb) = b.sin_cos();
    let (sc, cc) = c.sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]];
    let ry = [[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]];
    let rz = [[cc, -sc, 0.0], [sc, cc, 0.0], [0.0, 0.0, 1.0]];
    matmul(&matmul(&rx, &ry), &rz)
}

fn matmul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    out
}

fn apply(r: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| (0..3).map(|k| r[i][k] * v[k]).sum())
}

fn cross_norm(a: [f64; 3], b: [f64; 3]) -> f64 {
    let c = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
}

/// Directions closer than this (in sin of the angle) count as parallel: nominal directions are
/// exact or come from `rot` angles, so anything in between is a deliberate oblique axis.
const PARALLEL: f64 = 1e-9;

/// One frame of a chain, at the home position (every joint at 0), in the base's axes.
struct Placed {
    /// `true` for the tool chain.
    tool: bool,
    index: usize,
    axis: usize,
    kind: FrameKind,
    /// Frame k's axes in the base's: `R(0 → k)` at home, the product of the shapes' rotations
    /// (a joint at 0 is the identity, whichever side of it the frame sits).
    rotation: [[f64; 3]; 3],
}

fn placed(layout: &Layout<'_>) -> Vec<Placed> {
    let mut out = Vec::new();
    for (tool, chain) in [(true, layout.tool_chain), (false, layout.workpiece_chain)] {
        let mut r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        for (index, e) in chain.iter().enumerate() {
            r = matmul(&r, &shape_rotation(&e.shape));
            out.push(Placed {
                tool,
                index,
                axis: e.axis,
                kind: e.frame,
                rotation: r,
            });
        }
    }
    out
}

/// Which of the frame's components points along machine direction `dir`, and with which sign:
/// `Rᵀ e_dir` must be a unit vector of the frame.
fn aligned(p: &Placed, dir: usize, rotation: bool) -> Option<(Component, f64)> {
    let local = [0, 1, 2].map(|i| p.rotation[dir][i]);
    let i = (0..3).find(|&i| (local[i].abs() - 1.0).abs() < PARALLEL)?;
    let c = Component::ALL[i + if rotation { 3 } else { 0 }];
    Some((c, local[i].signum()))
}

/// A member of the structural loop a constant error can separate: an axis, or the workpiece
/// (whose frame defines the coordinates observations are in).
#[derive(Clone, Copy, PartialEq)]
enum Member {
    Axis(usize),
    Workpiece,
}

/// Whether a constant error of frame `p` moves `m` relative to the base: the frame's own joint
/// when the frame is fixed (the error sits before the joint, eq. 2.36–2.38), every element
/// after it in its chain, and for the workpiece chain the workpiece at its end.
fn carried(layout: &Layout<'_>, p: &Placed, m: Member) -> bool {
    let chain = if p.tool {
        layout.tool_chain
    } else {
        layout.workpiece_chain
    };
    match m {
        Member::Workpiece => !p.tool,
        Member::Axis(a) => chain.iter().enumerate().any(|(k, e)| {
            e.axis == a && (k > p.index || (k == p.index && p.kind == FrameKind::Fixed))
        }),
    }
}

/// Resolves an ISO 230-1 location or squareness name `E` + direction + `0` + axis
/// (spec/semantics.md, "Location and squareness"): `Ok(None)` when `name` is not of that form.
fn location<'a>(name: &str, layout: Layout<'a>) -> Result<Option<Aliased<'a>>, AliasError> {
    let mut chars = name.chars();
    let (Some('E'), Some(d), Some('0')) = (chars.next(), chars.next(), chars.next()) else {
        return Ok(None);
    };
    let rest = chars.as_str();
    let Some((rotation, dir)) = letter(d) else {
        return Ok(None);
    };
    let Some(j) = layout.axes.iter().position(|a| a.name == rest) else {
        return Ok(None);
    };
    let Some(axis) = layout.axes.get(j) else {
        return Ok(None);
    };
    let frames = placed(&layout);
    let Some(own) = frames.iter().find(|p| p.axis == j) else {
        return Err(AliasError::Unplaced {
            axis: axis.name.clone(),
        });
    };
    let dir_char = ['x', 'y', 'z'][dir];
    let mut e = [0.0; 3];
    e[dir] = 1.0;
    let direction = |p: &Placed| {
        apply(
            &p.rotation,
            layout
                .axes
                .get(p.axis)
                .map(|a| a.direction)
                .unwrap_or_default(),
        )
    };
    let parallel = cross_norm(direction(own), e) < PARALLEL;
    let not_aligned = |p: &Placed| AliasError::NotAligned {
        name: name.to_string(),
        frame: layout
            .axes
            .get(p.axis)
            .map(|a| a.name.clone())
            .unwrap_or_default(),
    };
    let at = |p: &Placed, sign: f64| -> Result<Option<Aliased<'a>>, AliasError> {
        let (component, s) = aligned(p, dir, rotation).ok_or_else(|| not_aligned(p))?;
        let axis = layout
            .axes
            .get(p.axis)
            .map(|a| a.name.as_str())
            .unwrap_or_default();
        Ok(Some(Aliased {
            axis,
            component,
            sign: sign * s,
        }))
    };
    match (axis.kind, rotation) {
        (JointKind::Prismatic, false) => Err(AliasError::LinearLocation {
            name: name.to_string(),
            axis: axis.name.clone(),
            dir: dir_char,
        }),
        (JointKind::Prismatic, true) if parallel => Err(AliasError::ParallelRotation {
            name: name.to_string(),
            axis: axis.name.clone(),
            dir: dir_char,
        }),
        (JointKind::Revolute, false) if parallel => Err(AliasError::AlongLine {
            name: name.to_string(),
            axis: axis.name.clone(),
            dir: dir_char,
        }),
        // The zero of a revolute axis: a rotation about its own line commutes with the joint,
        // so either side of it will do.
        (JointKind::Revolute, true) if parallel => at(own, 1.0),
        (JointKind::Revolute, _) => {
            if own.kind == FrameKind::Moving {
                return Err(AliasError::MovingRevolute {
                    name: name.to_string(),
                    axis: axis.name.clone(),
                });
            }
            at(own, 1.0)
        }
        (JointKind::Prismatic, true) => {
            // The other linear axes this rotation turns: the squareness is J's direction
            // relative to theirs; with none, relative to the workpiece's coordinates.
            let others: Vec<Member> = frames
                .iter()
                .filter(|p| p.axis != j)
                .filter(|p| {
                    layout.axes.get(p.axis).map(|a| a.kind) == Some(JointKind::Prismatic)
                        && cross_norm(direction(p), e) >= PARALLEL
                })
                .map(|p| Member::Axis(p.axis))
                .collect();
            let reference = if others.is_empty() {
                vec![Member::Workpiece]
            } else {
                others.clone()
            };
            // J's own frame first, then those of the reference axes, then any other.
            let mut order: Vec<&Placed> = vec![own];
            order.extend(
                frames
                    .iter()
                    .filter(|p| others.contains(&Member::Axis(p.axis))),
            );
            order.extend(
                frames
                    .iter()
                    .filter(|p| p.axis != j && !others.contains(&Member::Axis(p.axis))),
            );
            for p in order {
                let moves_j = carried(&layout, p, Member::Axis(j));
                let side = if moves_j && reference.iter().all(|&m| !carried(&layout, p, m)) {
                    1.0
                } else if !moves_j && reference.iter().all(|&m| carried(&layout, p, m)) {
                    -1.0
                } else {
                    continue;
                };
                if aligned(p, dir, true).is_some() {
                    return at(p, side);
                }
            }
            let names: Vec<String> = others
                .iter()
                .filter_map(|m| match m {
                    Member::Axis(a) => layout.axes.get(*a).map(|a| format!("`{}`", a.name)),
                    Member::Workpiece => None,
                })
                .collect();
            Err(AliasError::NoSeparatingFrame {
                name: name.to_string(),
                axis: axis.name.clone(),
                dir: dir_char,
                others: if names.is_empty() {
                    "the workpiece".to_string()
                } else {
                    names.join(", ")
                },
            })
        }
    }
}

/// The frame a parametric error belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum FrameRef {
    /// Element `k` (0-based) of the tool chain.
    Tool(usize),
    /// Element `k` (0-based) of the workpiece chain.
    Workpiece(usize),
    /// The tool frame `tl`: `None` for every tool, `Some(i)` for tool `i` only.
    ToolEnd(Option<usize>),
    /// The workpiece reference frame `wr`.
    WorkpieceEnd,
}

/// A scalar quantity of the observation state, in SI.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Var {
    Axis(usize),
    Input(usize),
    /// Output of `Machine::lags[i]`: a first-order lag of an input.
    Lag(usize),
    Time,
    /// Direction of motion of an axis: +1 or −1.
    Direction(usize),
}

/// A non-linear parameter: fixed, or fitted starting from `value`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NonLinear {
    /// Index into `Machine::nonlinear`.
    pub index: usize,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NonLinearParam {
    /// Report name, e.g. `Z.tz.tau`.
    pub name: String,
    pub value: f64,
    pub fitted: bool,
    pub unit: Unit,
}

/// Lag of an input (thesis eq. 3.41–3.48, normalised to unit steady-state gain): one stage
/// `dx/dt = (s − x) / τ`, or two in cascade (`lag(lag(…))`, a slow structure warmed by a
/// faster one), driven by `s = source(u)`, the heat-source relation of the input.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Lag {
    pub input: usize,
    /// Time constant of the first stage, the one the source drives.
    pub tau: NonLinear,
    /// What drives the first stage: the input itself, or a power of it (`pow(S / 1000 rpm, 1.5)`).
    #[serde(default)]
    pub source: LagSource,
    /// Time constant of a second stage driven by the first stage's output, if any.
    #[serde(default)]
    pub tau2: Option<NonLinear>,
    /// The input value (SI) held long enough before each run for every stage to settle there
    /// (`from 0 rpm`: the machine was at rest); `None` starts each run in steady state with its
    /// first input value.
    #[serde(default)]
    pub from: Option<f64>,
    /// A warm-up (`warmup(time, tau τ)`): driven by the constant 1 from the state 0 at each
    /// run's first row, `1 − e^{−(t − t₀)/τ}`; `input` is then unused (no input drives it).
    #[serde(default)]
    pub warmup: bool,
}

/// The heat-source relation of a lag: `s = (u / reference)^power`, `u` in SI.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LagSource {
    /// SI value the input is divided by (1 when the model writes none).
    pub reference: f64,
    /// A known exponent (1 for the input itself).
    pub power: f64,
}

impl Default for LagSource {
    fn default() -> Self {
        LagSource {
            reference: 1.0,
            power: 1.0,
        }
    }
}

impl LagSource {
    /// The drive `s` of an input value `u`. An integer power keeps the sign (`pow(F, 3)`); a
    /// non-integer power uses the magnitude, since the heat of a spindle or a feed does not
    /// depend on its direction and a negative base has no real non-integer power.
    pub fn drive(&self, u: f64) -> f64 {
        let x = u / self.reference;
        if self.power == 1.0 {
            x
        } else if self.power.fract() == 0.0 {
            libm::pow(x, self.power)
        } else {
            libm::pow(x.abs(), self.power)
        }
    }
}

impl Lag {
    /// The state every stage settles at while the input is held at `u`: unit steady-state gain.
    pub fn steady(&self, u: f64) -> f64 {
        if self.warmup {
            // A machine warmed long enough: the warm-up is complete.
            1.0
        } else {
            self.source.drive(u)
        }
    }
}

/// A known scalar: the scalings and fixed terms of the model, evaluated in SI.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Scalar {
    Num(f64),
    Var(Var),
    Neg(Box<Scalar>),
    Add(Box<Scalar>, Box<Scalar>),
    Sub(Box<Scalar>, Box<Scalar>),
    Mul(Box<Scalar>, Box<Scalar>),
    Div(Box<Scalar>, Box<Scalar>),
    Sin(Box<Scalar>),
    Cos(Box<Scalar>),
}

/// A basis factor: a family of dimensionless functions of one state variable.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BasisFactor {
    pub var: Var,
    pub basis: Basis,
}

/// One term of a parametric error: `scale · Π factors(state) · β`, with one coefficient per
/// combination of basis functions (a tensor product, row-major over `factors`). A term without
/// factors and without coefficients (`coefficients == 0`) is a known, fixed error `scale`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Term {
    pub scale: Scalar,
    pub factors: Vec<BasisFactor>,
    /// Index of this term's first coefficient in `Machine::coefficients`.
    pub first: usize,
    /// Number of coefficients: the product of the factors' sizes, or 0 for a fixed term.
    pub coefficients: usize,
}

impl Term {
    /// Whether the term is the same at every pose: no variable in its scale and only `const`
    /// factors (a location, an offset, a length — what a URDF can hold).
    pub fn is_constant(&self) -> bool {
        fn plain(s: &Scalar) -> bool {
            match s {
                Scalar::Num(_) => true,
                Scalar::Var(_) => false,
                Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => plain(a),
                Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
                    plain(a) && plain(b)
                }
            }
        }
        plain(&self.scale)
            && self
                .factors
                .iter()
                .all(|f| matches!(f.basis, crate::basis::Basis::Const))
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ErrorModel {
    pub frame: FrameRef,
    pub component: Component,
    pub terms: Vec<Term>,
}

/// A fitted linear coefficient β.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Coefficient {
    /// e.g. `Y.ty[3]`: the component's name and the index among that component's coefficients.
    pub name: String,
    /// What it multiplies, for reports, e.g. `spline(Y)#3 * linear(X)`.
    pub label: String,
    /// Index into `Machine::errors`.
    pub error: usize,
    /// The derived unit of the coefficient, for display (the value itself is kept in SI).
    pub unit: Unit,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Machine {
    pub name: String,
    pub task: Task,
    /// The unit direction gravity acts in, in the base's axes (`gravity along …`, −z by
    /// default): what deflects under it (spec/diagnosis.md, gravity rows).
    #[serde(default = "default_gravity")]
    pub gravity: [f64; 3],
    pub axes: Vec<Axis>,
    pub inputs: Vec<Input>,
    pub lags: Vec<Lag>,
    pub nonlinear: Vec<NonLinearParam>,
    pub tool_chain: Vec<Element>,
    pub workpiece_chain: Vec<Element>,
    /// At least one tool.
    pub tools: Vec<Tool>,
    pub workpiece: Shape,
    pub errors: Vec<ErrorModel>,
    pub coefficients: Vec<Coefficient>,
    /// Bound values of β in SI, when the source binds them (`params` block); else empty.
    pub beta: Vec<f64>,
    pub units: DisplayUnits,
}

/// Gravity when a model does not say: −z of the base, a machine standing with z up.
pub const GRAVITY: [f64; 3] = [0.0, 0.0, -1.0];

fn default_gravity() -> [f64; 3] {
    GRAVITY
}

/// The units the user asked for when quantities are printed or read without a unit.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DisplayUnits {
    pub length: Unit,
    pub angle: Unit,
    pub error: Unit,
    pub tilt: Unit,
    pub time: Unit,
    pub temperature: Unit,
    pub force: Unit,
}

#[cfg(test)]
mod tests {
    use super::{alias, AliasError, Aliased, Component, Machine};

    #[test]
    fn a_dh_chain_names_its_constants_as_a_robot_engineer_does_and_a_cmm_does_not() {
        let arm = crate::compile(
            "machine arm {
                task position
                axis J1 revolute about z range -180 deg .. 180 deg
                axis J2 revolute about z range -180 deg .. 180 deg
                axis S prismatic along z range 0 mm .. 100 mm
                tool chain { J1 moving  J2 moving at (0, 0, 100) mm rot (90, 0, 0) deg
                             S moving  tool t at (0, 0, 50) mm }
                errors { J2.rz = const  J2.tx = const + cos(J1) * const  J2.rx = const
                         S.tz = const  t.tz = const  workpiece.rz = const }
            }",
        );
        let m = &arm
            .compiled
            .unwrap_or_else(|| panic!("{:?}", arm.diagnostics))
            .machine;
        let names = m.robot_names();
        let named: Vec<(&str, Option<&str>)> = m
            .coefficients
            .iter()
            .zip(&names)
            .map(|(c, n)| (c.name.as_str(), n.as_deref()))
            .collect();
        assert_eq!(
            named,
            [
                ("J2.rz[0]", Some("joint offset")),
                ("J2.tx[0]", Some("link length δa")),
                // A term that varies with the pose is no DH parameter.
                ("J2.tx[1]", None),
                ("J2.rx[0]", Some("link twist δα")),
                ("S.tz[0]", Some("joint offset")),
                ("t.tz[0]", Some("tool z offset")),
                ("workpiece.rz[0]", Some("base rotation about z")),
            ]
        );
        let cmm = crate::compile(
            "machine cmm {
                task measure
                axis X prismatic along x range 0 mm .. 600 mm
                axis Z prismatic along z range -450 mm .. 0 mm
                tool chain { X moving  Z moving  tool probe }
                errors { X.tx = const  Z.tz = const }
            }",
        );
        let m = &cmm
            .compiled
            .unwrap_or_else(|| panic!("{:?}", cmm.diagnostics))
            .machine;
        assert!(m.robot_names().iter().all(Option::is_none));
    }

    /// A bridge CMM: Y carries X carries Z, every frame moving (examples/bridge_cmm.kin).
    const BRIDGE: &str = "machine bridge {
        task measure
        axis Y prismatic along y range 0 mm .. 700 mm
        axis X prismatic along x range 0 mm .. 600 mm
        axis Z prismatic along z range -450 mm .. 0 mm
        tool chain { Y moving  X moving  Z moving  tool probe at (0, 0, -120) mm }
    }";

    /// A table-table mill: Y, X, A, C carry the part (fixed frames), Z the spindle.
    const MILL: &str = "machine mill {
        task position
        axis Y prismatic along -y range 0 mm .. 500 mm
        axis X prismatic along -x range 0 mm .. 650 mm
        axis Z prismatic along z range -450 mm .. 0 mm
        axis A revolute about x range -120 deg .. 30 deg
        axis C revolute about z continuous
        workpiece chain { Y fixed  X fixed  A fixed at (0, 0, 230) mm  C fixed }
        tool chain { Z moving at (0, 0, 760) mm  tool t }
    }";

    fn machine(src: &str) -> Machine {
        crate::compile(src).compiled.expect("compiles").machine
    }

    fn resolve(m: &Machine, name: &str) -> Result<Option<(String, Component, f64)>, AliasError> {
        Ok(alias(name, m.layout())?.map(
            |Aliased {
                 axis,
                 component,
                 sign,
             }| (axis.to_string(), component, sign),
        ))
    }

    #[test]
    fn squareness_names_land_on_the_frame_between_the_two_axes() {
        let m = machine(BRIDGE);
        let r = |n| resolve(&m, n).expect(n).expect(n);
        // X rides on Y: Y's constant yaw turns X (and Z, along the axis of the rotation) against
        // Y, which is Y turned the other way against X.
        assert_eq!(r("EC0Y"), ("Y".into(), Component::Rz, -1.0));
        assert_eq!(r("EC0X"), ("Y".into(), Component::Rz, 1.0));
        assert_eq!(r("EB0Z"), ("X".into(), Component::Ry, 1.0));
        assert_eq!(r("EA0Z"), ("Y".into(), Component::Rx, 1.0));
        // Component errors keep their meaning.
        assert_eq!(r("ECY"), ("Y".into(), Component::Rz, 1.0));

        let m = machine(MILL);
        let r = |n| resolve(&m, n).expect(n).expect(n);
        assert_eq!(r("EC0Y"), ("X".into(), Component::Rz, -1.0));
        assert_eq!(r("EB0Z"), ("X".into(), Component::Ry, -1.0));
        assert_eq!(r("EA0Z"), ("Y".into(), Component::Rx, -1.0));
        // Location of the rotary axes: their fixed frames.
        assert_eq!(r("EX0C"), ("C".into(), Component::Tx, 1.0));
        assert_eq!(r("EY0C"), ("C".into(), Component::Ty, 1.0));
        assert_eq!(r("EA0C"), ("C".into(), Component::Rx, 1.0));
        assert_eq!(r("EB0C"), ("C".into(), Component::Ry, 1.0));
        assert_eq!(r("EC0C"), ("C".into(), Component::Rz, 1.0));
        assert_eq!(r("EY0A"), ("A".into(), Component::Ty, 1.0));
        assert_eq!(r("EC0A"), ("A".into(), Component::Rz, 1.0));
    }

    #[test]
    fn names_the_structure_cannot_carry_say_why() {
        let m = machine(MILL);
        assert!(matches!(
            resolve(&m, "EA0X"),
            Err(AliasError::ParallelRotation { .. })
        ));
        assert!(matches!(
            resolve(&m, "EY0X"),
            Err(AliasError::LinearLocation { .. })
        ));
        assert!(matches!(
            resolve(&m, "EZ0C"),
            Err(AliasError::AlongLine { .. })
        ));
        assert_eq!(resolve(&m, "EQ0C"), Ok(None));
        assert_eq!(resolve(&m, "EC0W"), Ok(None));
        // Y fixed carries X, X moving carries nothing between them: no frame separates them.
        let m = machine(
            "machine m { task position
                axis Y prismatic along y range 0 mm .. 500 mm
                axis X prismatic along x range 0 mm .. 500 mm
                workpiece chain { Y fixed  X moving }
                tool chain { tool t } }",
        );
        assert!(matches!(
            resolve(&m, "EC0Y"),
            Err(AliasError::NoSeparatingFrame { .. })
        ));
        // A moving rotary frame turns its errors with the table: no location there.
        let m = machine(
            "machine m { task position
                axis C revolute about z continuous
                workpiece chain { C moving }
                tool chain { tool t } }",
        );
        assert!(matches!(
            resolve(&m, "EX0C"),
            Err(AliasError::MovingRevolute { .. })
        ));
        assert_eq!(
            resolve(&m, "EC0C").expect("zero of C").map(|a| a.2),
            Some(1.0)
        );
    }

    #[test]
    fn a_frame_turned_by_rot_maps_with_its_own_axes() {
        // C's frame is turned 180° about x: its z points down, so EA0C and EC0C change sign.
        let m = machine(
            "machine m { task position
                axis C revolute about z continuous
                workpiece chain { C fixed rot (180, 0, 0) deg }
                tool chain { tool t } }",
        );
        let r = |n| resolve(&m, n).expect(n).expect(n);
        assert_eq!(r("EX0C"), ("C".into(), Component::Tx, 1.0));
        assert_eq!(r("EY0C"), ("C".into(), Component::Ty, -1.0));
        assert_eq!(r("EC0C"), ("C".into(), Component::Rz, -1.0));
    }

    #[test]
    fn coefficients_are_named_by_iso_too() {
        let m = machine(
            "machine mill {
                task position
                axis Y prismatic along -y range 0 mm .. 500 mm
                axis X prismatic along -x range 0 mm .. 650 mm
                axis Z prismatic along z range -450 mm .. 0 mm
                axis C revolute about z continuous
                workpiece chain { Y fixed  X fixed  C fixed }
                tool chain { Z moving  tool t }
                errors {
                    X.rz = const + spline(X, knots 2)
                    EC0Y += const
                    EX0C = const
                    Z.tz = const
                }
            }",
        );
        let names: Vec<(String, Option<String>)> = m
            .coefficients
            .iter()
            .map(|c| c.name.clone())
            .zip(m.iso_names())
            .collect();
        let get = |n: &str| {
            names
                .iter()
                .find(|(c, _)| c == n)
                .and_then(|(_, i)| i.clone())
                .unwrap_or_default()
        };
        let last = names.iter().filter(|(c, _)| c.starts_with("X.rz[")).count() - 1;
        // `const` on X.rz is −EC0Y; `EC0Y += const` wrote −const there, so it is EC0Y.
        assert_eq!(get("X.rz[0]"), "-EC0Y");
        assert_eq!(get("X.rz[1]"), "ECX");
        assert_eq!(get(&format!("X.rz[{last}]")), "EC0Y");
        assert_eq!(get("C.tx[0]"), "EX0C");
        assert_eq!(get("Z.tz[0]"), "EZZ");
    }
}
