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

/// The axis and component an ISO 230-1 name (`EXX`, `EBZ`: E, error direction, axis) or a
/// VDI 2617 name (`xtx`, `yrz`: axis, translation/rotation, direction) of an axis error stands
/// for; `None` when `name` is neither, for these `axes`.
pub fn alias<'a>(name: &str, axes: &'a [Axis]) -> Option<(&'a str, Component)> {
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
            }?;
            return Some((axis.name.as_str(), c));
        }
    }
    let chars: Vec<char> = name.chars().collect();
    if let [a, k, d] = chars.as_slice() {
        let axis = axes
            .iter()
            .find(|ax| ax.name.to_lowercase() == a.to_string())?;
        return Some((axis.name.as_str(), component(*k, *d)?));
    }
    None
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

/// First-order lag of an input (thesis eq. 3.41–3.48, normalised to unit steady-state gain):
/// `dx/dt = (u − x) / τ`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Lag {
    pub input: usize,
    pub tau: NonLinear,
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
