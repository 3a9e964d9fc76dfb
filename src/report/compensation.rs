//! The report's compensation section: the fitted model's predicted error before and after
//! software compensation (thesis §2.3.5, `kin_model::compensate`) along each axis, and what
//! the axes cannot correct.
//!
//! Each axis is swept over its declared range with the others held at the middle of theirs;
//! at every point the commanded pose is compensated exactly as `kin compensate` does it (the
//! exact transforms, every component weighed) and the position and orientation errors before
//! and after are kept. A remaining position error means the joints cannot move the tool that
//! way there; a remaining orientation error is usually a machine with fewer than three rotary
//! axes, which no correction of its axes turns.

use kin_compiler::ir::{JointKind, Machine, Var};
use kin_model::compensate::{Compensator, Options};
use kin_model::interp::State;

/// Points per axis sweep.
const POINTS: usize = 41;

/// One axis swept over its range.
pub struct Sweep {
    pub axis: String,
    /// The axis's unit.
    pub unit: String,
    /// Positions along the axis, in its unit.
    pub x: Vec<f64>,
    /// Length of the position error, in the model's error unit, before and after compensation.
    pub before: Vec<f64>,
    pub after: Vec<f64>,
    /// Size of the orientation error, in the model's tilt unit, before and after.
    pub tilt_before: Vec<f64>,
    pub tilt_after: Vec<f64>,
    /// The fewest independent components the joints could move along the sweep.
    pub rank: usize,
}

/// The whole section, or why there is none.
pub struct View {
    pub sweeps: Vec<Sweep>,
    /// What the other variables are held at, as text.
    pub reference: Vec<String>,
    pub error_unit: String,
    pub tilt_unit: String,
}

/// Sweeps every axis of `m` (with the fitted values bound) through the compensation; `held`
/// gives the value of each input (SI) where the data told it, else its declared range's middle,
/// else 20 °C for an absolute temperature and 0 for a rise.
pub fn sweeps(m: &Machine, held: &dyn Fn(Var) -> Option<f64>) -> Result<View, String> {
    let mut comp = Compensator::new(m, &m.beta, Options::pose(m)).map_err(|e| e.to_string())?;
    let unit_of = |kind: JointKind| match kind {
        JointKind::Prismatic => &m.units.length,
        JointKind::Revolute => &m.units.angle,
    };
    let middle: Vec<f64> = m
        .axes
        .iter()
        .map(|a| {
            if a.continuous {
                0.0
            } else {
                0.5 * (a.range[0] + a.range[1])
            }
        })
        .collect();
    let inputs: Vec<f64> = m
        .inputs
        .iter()
        .enumerate()
        .map(|(i, input)| {
            held(Var::Input(i))
                .or(input.range.map(|[lo, hi]| 0.5 * (lo + hi)))
                .unwrap_or(if input.absolute { 293.15 } else { 0.0 })
        })
        .collect();
    // Lags in steady state: each at its input's value.
    let lags: Vec<f64> = m
        .lags
        .iter()
        .map(|l| l.steady(inputs.get(l.input).copied().unwrap_or(0.0)))
        .collect();
    let time = held(Var::Time).unwrap_or(0.0);
    let dirs = vec![1.0; m.axes.len()];
    let mut reference: Vec<String> = m
        .axes
        .iter()
        .zip(&middle)
        .map(|(a, v)| {
            let u = unit_of(a.kind);
            format!("{} = {} {}", a.name, super::num(u.from_si(*v), 4), u.name)
        })
        .collect();
    for (input, v) in m.inputs.iter().zip(&inputs) {
        reference.push(format!(
            "{} = {} {}",
            input.name,
            super::num(input.unit.from_si(*v), 4),
            input.unit.name
        ));
    }
    reference.push("directions of motion positive, the first tool".into());
    let mut sweeps = Vec::new();
    for (k, axis) in m.axes.iter().enumerate() {
        let [lo, hi] = if axis.continuous {
            [0.0, 2.0 * std::f64::consts::PI]
        } else {
            axis.range
        };
        let u = unit_of(axis.kind);
        let mut s = Sweep {
            axis: axis.name.clone(),
            unit: u.name.clone(),
            x: Vec::with_capacity(POINTS),
            before: Vec::with_capacity(POINTS),
            after: Vec::with_capacity(POINTS),
            tilt_before: Vec::with_capacity(POINTS),
            tilt_after: Vec::with_capacity(POINTS),
            rank: usize::MAX,
        };
        let mut q = middle.clone();
        for p in 0..POINTS {
            let v = lo + (hi - lo) * p as f64 / (POINTS - 1) as f64;
            if let Some(slot) = q.get_mut(k) {
                *slot = v;
            }
            let state = State {
                q: &q,
                inputs: &inputs,
                lags: &lags,
                time,
                dirs: &dirs,
                tool: 0,
                tool_offset: None,
            };
            let c = comp.compensate(&state).map_err(|e| e.to_string())?;
            let norm = |e: &[f64]| e.iter().map(|x| x * x).sum::<f64>().sqrt();
            s.x.push(u.from_si(v));
            s.before.push(m.units.error.from_si(norm(&c.before[..3])));
            s.after.push(m.units.error.from_si(norm(&c.after[..3])));
            s.tilt_before
                .push(m.units.tilt.from_si(norm(&c.before[3..])));
            s.tilt_after.push(m.units.tilt.from_si(norm(&c.after[3..])));
            s.rank = s.rank.min(c.rank);
        }
        sweeps.push(s);
    }
    Ok(View {
        sweeps,
        reference,
        error_unit: m.units.error.name.clone(),
        tilt_unit: m.units.tilt.name.clone(),
    })
}
