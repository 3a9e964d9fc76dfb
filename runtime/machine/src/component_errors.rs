//! ISO 230-1 component errors of each axis, computed from the model: what a parametric
//! ("volumetric") compensation such as ISG / Beckhoff TwinCAT VolComp reads as one table per
//! axis, `X EXX EYX EZX EAX EBX ECX`.
//!
//! ISO 230-1 names the error motions of an axis by the direction of the error and the axis:
//! `EXX` (positioning), `EYX`, `EZX` (straightness), `EAX`, `EBX`, `ECX` (roll, pitch, yaw
//! about x, y, z), all in the machine's coordinate axes. The thesis (ch. 2, eq. 2.8) holds the
//! same six quantities as the parametric errors `E_k = (tx, ty, tz, rx, ry, rz)` of the element
//! the axis moves, in that element's own frame. The mapping is a change of axes and a sign:
//!
//! ```text
//! ε_j = s_k · ( R_k d_k ,  R_k e_k )        (one element k driven by axis j)
//! ```
//!
//! with `R_k` the axes of frame k in the base (machine) frame at the pose, `d_k`, `e_k` the
//! translation and rotation parts of `E_k`, and `s_k = +1` for an element of the tool chain,
//! `−1` for one of the workpiece chain (eq. 2.24: an error of a carriage that moves the
//! workpiece displaces the tool relative to the workpiece the other way). So every table is the
//! axis's error motion *as seen by the tool relative to the workpiece*, as if every axis were on
//! the tool side; the translations are those of the frame's origin (its reference point). The
//! Abbe terms (an angular error seen at the tool through the arm from that point) are not in the
//! table: the controller adds them from its own kinematic description.

use kin_compiler::ir::{FrameRef, Machine};
use nalgebra::{Matrix3, Vector3};
use thiserror::Error;

use kin_model::interp::{EvalError, Interpreter, State};
use kin_model::kinematics::{FirstOrderModel, FrameErrors, KinematicsError, Pose, Sensitivities};

#[derive(Debug, Error)]
pub enum ComponentError {
    #[error(
        "axis {0} moves {1} elements of the chains; a table of component errors describes one carriage per axis"
    )]
    Elements(String, usize),
    #[error("axis {0} moves no element of either chain")]
    Unused(String),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
}

/// The one chain element axis `axis` drives.
pub(crate) fn element_of(m: &Machine, axis: usize) -> Result<FrameRef, ComponentError> {
    let frames: Vec<FrameRef> = m
        .tool_chain
        .iter()
        .enumerate()
        .filter(|(_, e)| e.axis == axis)
        .map(|(k, _)| FrameRef::Tool(k))
        .chain(
            m.workpiece_chain
                .iter()
                .enumerate()
                .filter(|(_, e)| e.axis == axis)
                .map(|(k, _)| FrameRef::Workpiece(k)),
        )
        .collect();
    let name = || {
        m.axes
            .get(axis)
            .map_or("?", |a| a.name.as_str())
            .to_string()
    };
    match frames.as_slice() {
        [one] => Ok(*one),
        [] => Err(ComponentError::Unused(name())),
        many => Err(ComponentError::Elements(name(), many.len())),
    }
}

/// `s_k R_k`: the map from frame k's axes to machine axes, with the side's sign (module docs).
fn to_machine(sens: &Sensitivities, frame: FrameRef) -> Matrix3<f64> {
    let sign = match frame {
        FrameRef::Workpiece(_) => -1.0,
        _ => 1.0,
    };
    sens.base_rotation(frame).unwrap_or_else(Matrix3::identity) * sign
}

/// Evaluates component errors along the chain; holds the scratch of one pose.
pub struct Components<'m> {
    m: &'m Machine,
    beta: &'m [f64],
    it: Interpreter<'m>,
    first: FirstOrderModel,
    sens: Sensitivities,
    errors: FrameErrors,
}

impl<'m> Components<'m> {
    pub fn new(m: &'m Machine, beta: &'m [f64]) -> Result<Self, ComponentError> {
        let first = FirstOrderModel::new(m)?;
        let sens = first.sensitivities();
        Ok(Components {
            m,
            beta,
            it: Interpreter::new(m)?,
            first,
            sens,
            errors: FrameErrors::zeros(m),
        })
    }

    /// The interpreter evaluating the model (to set fitted non-linear parameters).
    pub fn interpreter(&mut self) -> &mut Interpreter<'m> {
        &mut self.it
    }

    /// `(EX, EY, EZ, EA, EB, EC)` of axis `axis` at `state` (m, rad, machine axes): the
    /// model's parametric errors of the element it drives, mapped as in the module docs.
    pub fn at(&mut self, state: &State, axis: usize) -> Result<[f64; 6], ComponentError> {
        let frame = element_of(self.m, axis)?;
        self.it.frame_errors(state, self.beta, &mut self.errors)?;
        let pose = Pose {
            q: state.q,
            tool: state.tool,
            tool_offset: state.tool_offset,
        };
        self.first.evaluate(&pose, &mut self.sens)?;
        let e = self.errors.get(frame).copied().unwrap_or([0.0; 6]);
        let a = to_machine(&self.sens, frame);
        let d = a * Vector3::new(e[0], e[1], e[2]);
        let r = a * Vector3::new(e[3], e[4], e[5]);
        Ok([d.x, d.y, d.z, r.x, r.y, r.z])
    }

    /// The model's predicted position error at `state` (first order, positioning sign, wr
    /// axes) and the one the component `tables` imply when composed along the chain as the
    /// model composes its parametric errors (each axis's element given the table's values,
    /// every other error zero). Their difference is what the tables leave out.
    pub(crate) fn model_and_tables(
        &mut self,
        state: &State,
        tables: &[ComponentTable],
    ) -> Result<([f64; 3], [f64; 3]), ComponentError> {
        self.it.frame_errors(state, self.beta, &mut self.errors)?;
        let pose = Pose {
            q: state.q,
            tool: state.tool,
            tool_offset: state.tool_offset,
        };
        self.first.evaluate(&pose, &mut self.sens)?;
        let model = self.sens.first_order_error(&self.errors)?;
        let mut implied = FrameErrors::zeros(self.m);
        for t in tables {
            let frame = element_of(self.m, t.axis)?;
            let q = state.q.get(t.axis).copied().unwrap_or(0.0);
            let v = t.value(q);
            // s R is orthogonal up to its sign, so its inverse is its transpose.
            let back = to_machine(&self.sens, frame).transpose();
            let d = back * Vector3::new(v[0], v[1], v[2]);
            let r = back * Vector3::new(v[3], v[4], v[5]);
            if let Some(slot) = implied.get_mut(frame) {
                *slot = [d.x, d.y, d.z, r.x, r.y, r.z];
            }
        }
        let tables = self.sens.first_order_error(&implied)?;
        Ok((
            [model[0], model[1], model[2]],
            [tables[0], tables[1], tables[2]],
        ))
    }
}

/// The component errors of one axis at nominal positions of it, in SI and machine axes.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ComponentTable {
    /// Index into `Machine::axes`.
    pub axis: usize,
    /// Positions of the axis, ascending.
    pub nominal: Vec<f64>,
    /// `(EX, EY, EZ, EA, EB, EC)` at each position: the mean of the two directions of motion.
    pub values: Vec<[f64; 6]>,
    /// The largest half-difference between the directions (the reversal a table of position
    /// alone cannot hold): translations (m), rotations (rad).
    pub reversal: [f64; 2],
    /// The largest difference, at the midpoints between positions, between the model and the
    /// table's linear interpolation: translations (m), rotations (rad).
    pub interpolation_error: [f64; 2],
}

impl ComponentTable {
    /// Linear interpolation between positions, held at the end values outside them.
    pub fn value(&self, position: f64) -> [f64; 6] {
        let n = self.nominal.len().min(self.values.len());
        let at = |i: usize| self.values.get(i).copied().unwrap_or([0.0; 6]);
        let (Some(&first), Some(&last)) =
            (self.nominal.first(), self.nominal.get(n.wrapping_sub(1)))
        else {
            return [0.0; 6];
        };
        if position <= first {
            return at(0);
        }
        if position >= last {
            return at(n - 1);
        }
        let k = self
            .nominal
            .partition_point(|x| *x <= position)
            .saturating_sub(1);
        let (a, b) = (
            self.nominal.get(k).copied().unwrap_or(first),
            self.nominal.get(k + 1).copied().unwrap_or(last),
        );
        let t = if b > a { (position - a) / (b - a) } else { 0.0 };
        let (lo, hi) = (at(k), at(k + 1));
        std::array::from_fn(|c| lo[c] + t * (hi[c] - lo[c]))
    }
}

/// Splits a 6-vector's largest absolute translation and rotation.
fn largest(v: &[f64; 6]) -> [f64; 2] {
    let max = |s: &[f64]| s.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    [max(&v[..3]), max(&v[3..])]
}

/// The table of axis `axis` at positions `nodes` (ascending); every other axis, the tool and
/// the inputs as in `reference`. Each value is the mean over the two directions of motion of
/// the axis (the format holds no direction); what that drops is reported as `reversal`.
pub(crate) fn component_table(
    c: &mut Components<'_>,
    reference: &State,
    axis: usize,
    nodes: &[f64],
) -> Result<ComponentTable, ComponentError> {
    element_of(c.m, axis)?;
    let mut q = reference.q.to_vec();
    let mut dirs = reference.dirs.to_vec();
    let mut both = |position: f64| -> Result<([f64; 6], [f64; 6]), ComponentError> {
        if let Some(slot) = q.get_mut(axis) {
            *slot = position;
        }
        let mut value = |dir: f64| {
            if let Some(slot) = dirs.get_mut(axis) {
                *slot = dir;
            }
            let state = State {
                q: &q,
                dirs: &dirs,
                ..*reference
            };
            c.at(&state, axis)
        };
        let (f, r) = (value(1.0)?, value(-1.0)?);
        let mean = std::array::from_fn(|k| 0.5 * (f[k] + r[k]));
        let half = std::array::from_fn(|k| 0.5 * (f[k] - r[k]));
        Ok((mean, half))
    };
    let mut table = ComponentTable {
        axis,
        nominal: nodes.to_vec(),
        values: Vec::with_capacity(nodes.len()),
        reversal: [0.0; 2],
        interpolation_error: [0.0; 2],
    };
    for &p in nodes {
        let (mean, half) = both(p)?;
        table.values.push(mean);
        let [t, r] = largest(&half);
        table.reversal = [table.reversal[0].max(t), table.reversal[1].max(r)];
    }
    for pair in nodes.windows(2) {
        let mid = 0.5 * (pair[0] + pair[1]);
        let (model, _) = both(mid)?;
        let interpolated = table.value(mid);
        let miss: [f64; 6] = std::array::from_fn(|k| model[k] - interpolated[k]);
        let [t, r] = largest(&miss);
        table.interpolation_error = [
            table.interpolation_error[0].max(t),
            table.interpolation_error[1].max(r),
        ];
    }
    Ok(table)
}

#[cfg(test)]
mod tests {
    use super::*;
    use kin_compiler::compile;

    /// A table X (workpiece side, along −x) under a column Y and ram Z (tool side).
    const MILL: &str = r#"
machine mill3 {
    task position
    units { length mm, error um, tilt urad }
    axis X prismatic along -x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 400 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    tool chain { Y moving  Z moving at (0, 0, 400) mm  tool t at (0, 0, -100) mm }
    workpiece chain { X fixed  workpiece }
    errors {
        X.tx = linear(X) + backlash(X)
        X.ty = linear(X)
        Y.rz = const
        Z.tx = const
    }
}
"#;

    fn state<'a>(q: &'a [f64], dirs: &'a [f64]) -> State<'a> {
        State {
            q,
            inputs: &[],
            lags: &[],
            time: 0.0,
            dirs,
            tool: 0,
            tool_offset: None,
        }
    }

    #[test]
    fn workpiece_side_errors_change_sign_and_tool_side_keep_it() {
        let c = compile(MILL).compiled.expect("compiles");
        let m = &c.machine;
        // X.tx = 10 µm·(2X/500 − 1) + 2 µm·dir; X.ty = 4 µm·(2X/500 − 1); Y.rz 7 µrad; Z.tx 3 µm.
        let beta = vec![10e-6, 2e-6, 4e-6, 7e-6, 3e-6];
        assert_eq!(beta.len(), m.coefficients.len());
        let mut comp = Components::new(m, &beta).expect("components");
        let q = [0.5, 0.2, -0.1];
        let dirs = [1.0; 3];
        // X at its end: tx = 10 + 2 µm along the frame's x. The frame's axes are the
        // machine's; the table moves the workpiece, so the tool sees −12 µm in x, −4 µm in y.
        let x = comp.at(&state(&q, &dirs), 0).expect("X");
        assert!((x[0] + 12e-6).abs() < 1e-15, "{x:?}");
        assert!((x[1] + 4e-6).abs() < 1e-15, "{x:?}");
        let y = comp.at(&state(&q, &dirs), 1).expect("Y");
        assert!((y[5] - 7e-6).abs() < 1e-15, "{y:?}");
        let z = comp.at(&state(&q, &dirs), 2).expect("Z");
        assert!((z[0] - 3e-6).abs() < 1e-15, "{z:?}");

        let nodes = [0.0, 0.25, 0.5];
        let t = component_table(&mut comp, &state(&q, &dirs), 0, &nodes).expect("table");
        // The mean of both directions drops the backlash; its half-difference is reported.
        assert!((t.values[2][0] + 10e-6).abs() < 1e-15, "{t:?}");
        assert!((t.reversal[0] - 2e-6).abs() < 1e-15, "{t:?}");
        // Linear errors interpolate exactly.
        assert!(t.interpolation_error[0] < 1e-15, "{t:?}");
    }

    #[test]
    fn tables_composed_along_the_chain_reproduce_the_model() {
        let c = compile(MILL).compiled.expect("compiles");
        let m = &c.machine;
        let beta = vec![10e-6, 0.0, 4e-6, 7e-6, 3e-6];
        let mut comp = Components::new(m, &beta).expect("components");
        let q = [0.25, 0.2, -0.15];
        let dirs = [1.0; 3];
        let reference = state(&q, &dirs);
        let tables: Vec<ComponentTable> = [
            (0, vec![0.0, 0.5]),
            (1, vec![0.0, 0.4]),
            (2, vec![-0.3, 0.0]),
        ]
        .into_iter()
        .map(|(j, nodes)| component_table(&mut comp, &reference, j, &nodes).expect("table"))
        .collect();
        for q in [[0.1, 0.3, -0.2], [0.45, 0.05, -0.01]] {
            let (model, implied) = comp
                .model_and_tables(&state(&q, &dirs), &tables)
                .expect("evaluates");
            for k in 0..3 {
                assert!(
                    (model[k] - implied[k]).abs() < 1e-15,
                    "{model:?} {implied:?}"
                );
            }
            assert!(model.iter().any(|v| v.abs() > 1e-6), "{model:?}");
        }
    }
}
