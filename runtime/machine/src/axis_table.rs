//! Per-axis compensation tables: what a controller's leadscrew (pitch) and backlash
//! compensation holds. One table per axis gives, at nominal positions of that axis, the
//! correction to add to its command for each direction of motion, interpolated linearly
//! between the positions.
//!
//! Such a table is a function of one axis's own position and direction only, so it can hold
//! only the part of the modelled error that moving that axis takes out, evaluated with the
//! other axes at one reference pose. Cross-couplings (an error of one axis depending on another
//! axis's position), angular errors with their Abbe offsets away from the reference pose,
//! straightness and squareness, and terms of the inputs (thermal, load) are not in it: the
//! functions here measure what is lost rather than hiding it.

use kin_compiler::units::Unit;

use kin_model::compensate::{CompensateError, Compensator};
use kin_model::interp::State;

/// The table of one axis, in SI.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisTable {
    /// Index into `Machine::axes`.
    pub axis: usize,
    /// Nominal (commanded) positions, ascending.
    pub nominal: Vec<f64>,
    /// The correction to add to the command when the axis moves in the positive direction …
    pub forward: Vec<f64>,
    /// … and in the negative direction.
    pub reverse: Vec<f64>,
    /// The largest difference, at the midpoints between nominal positions, between the
    /// model's correction and the table's linear interpolation (either direction).
    pub interpolation_error: f64,
}

/// The table of `axis` at the positions `nodes` (ascending), every other axis, the tool and
/// the inputs as in `reference`. Each value is the correction of the axis alone that
/// minimises the weighted predicted error (the compensator's solve with only this axis free).
pub(crate) fn axis_table(
    comp: &mut Compensator<'_>,
    reference: &State,
    axis: usize,
    nodes: &[f64],
) -> Result<AxisTable, CompensateError> {
    let axes = reference.q.len();
    let mut free = vec![false; axes];
    if let Some(f) = free.get_mut(axis) {
        *f = true;
    }
    let mut q = reference.q.to_vec();
    let mut dirs = reference.dirs.to_vec();
    let mut correction = |position: f64, dir: f64| -> Result<f64, CompensateError> {
        if let Some(slot) = q.get_mut(axis) {
            *slot = position;
        }
        if let Some(slot) = dirs.get_mut(axis) {
            *slot = dir;
        }
        let state = State {
            q: &q,
            dirs: &dirs,
            ..*reference
        };
        let c = comp.compensate_with(&state, Some(&free))?;
        Ok(c.dq.get(axis).copied().unwrap_or(0.0))
    };
    let mut table = AxisTable {
        axis,
        nominal: nodes.to_vec(),
        forward: Vec::with_capacity(nodes.len()),
        reverse: Vec::with_capacity(nodes.len()),
        interpolation_error: 0.0,
    };
    for &p in nodes {
        table.forward.push(correction(p, 1.0)?);
        table.reverse.push(correction(p, -1.0)?);
    }
    for (k, pair) in nodes.windows(2).enumerate() {
        let [a, b] = [pair[0], pair[1]];
        let mid = 0.5 * (a + b);
        for (dir, values) in [(1.0, &table.forward), (-1.0, &table.reverse)] {
            let model = correction(mid, dir)?;
            let lo = values.get(k).copied().unwrap_or(0.0);
            let hi = values.get(k + 1).copied().unwrap_or(0.0);
            let miss = (model - 0.5 * (lo + hi)).abs();
            table.interpolation_error = table.interpolation_error.max(miss);
        }
    }
    Ok(table)
}

/// The full compensation (every axis free) at positions of one axis, the others, the tool and
/// the inputs as in a reference pose: what a controller's own-axis tables (the diagonal) and
/// its cross-axis ("sag") tables (the correction of another axis as a function of this one)
/// hold. Corrections are indexed like `Machine::axes`, in SI.
#[derive(Debug, Clone, PartialEq)]
pub struct Sweep {
    /// Index into `Machine::axes` of the swept axis.
    pub axis: usize,
    /// Its nominal positions, ascending.
    pub nominal: Vec<f64>,
    /// The corrections of every axis at each position, the swept axis moving in + …
    pub forward: Vec<Vec<f64>>,
    /// … and moving in −.
    pub reverse: Vec<Vec<f64>>,
    /// The same at the midpoints between positions (for the interpolation error).
    pub mid_forward: Vec<Vec<f64>>,
    pub mid_reverse: Vec<Vec<f64>>,
}

/// Compensates `reference` with axis `axis` at each of `nodes` and at their midpoints, in
/// both directions of that axis, moving only the axes `free` marks (every axis when `None`):
/// the axes the tables being written can move.
pub fn sweep(
    comp: &mut Compensator<'_>,
    reference: &State,
    axis: usize,
    nodes: &[f64],
    free: Option<&[bool]>,
) -> Result<Sweep, CompensateError> {
    let mut q = reference.q.to_vec();
    let mut dirs = reference.dirs.to_vec();
    let mut correction = |position: f64, dir: f64| -> Result<Vec<f64>, CompensateError> {
        if let Some(slot) = q.get_mut(axis) {
            *slot = position;
        }
        if let Some(slot) = dirs.get_mut(axis) {
            *slot = dir;
        }
        let state = State {
            q: &q,
            dirs: &dirs,
            ..*reference
        };
        Ok(comp.compensate_with(&state, free)?.dq)
    };
    let mids: Vec<f64> = nodes.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
    let mut run = |points: &[f64], dir: f64| -> Result<Vec<Vec<f64>>, CompensateError> {
        points.iter().map(|&p| correction(p, dir)).collect()
    };
    Ok(Sweep {
        axis,
        nominal: nodes.to_vec(),
        forward: run(nodes, 1.0)?,
        reverse: run(nodes, -1.0)?,
        mid_forward: run(&mids, 1.0)?,
        mid_reverse: run(&mids, -1.0)?,
    })
}

impl Sweep {
    /// The correction of axis `output` along the swept axis as a table over the swept axis's
    /// positions. `cross: None` keeps the two directions (the swept axis's own table, where a
    /// backlash shows); `Some(offset)` gives a table of either direction, the mean of both less
    /// `offset` (the output's correction at the reference pose, which its own table already
    /// holds), as a cross-axis table adds to the output's own.
    pub fn table(&self, output: usize, cross: Option<f64>) -> AxisTable {
        let pick = |rows: &[Vec<f64>]| -> Vec<f64> {
            rows.iter()
                .map(|r| r.get(output).copied().unwrap_or(0.0))
                .collect()
        };
        let (mut forward, mut reverse) = (pick(&self.forward), pick(&self.reverse));
        let (mut mid_f, mut mid_r) = (pick(&self.mid_forward), pick(&self.mid_reverse));
        if let Some(offset) = cross {
            let mean = |a: &mut Vec<f64>, b: &mut Vec<f64>| {
                for (x, y) in a.iter_mut().zip(b.iter_mut()) {
                    let m = 0.5 * (*x + *y) - offset;
                    *x = m;
                    *y = m;
                }
            };
            mean(&mut forward, &mut reverse);
            mean(&mut mid_f, &mut mid_r);
        }
        let mut interpolation_error = 0.0_f64;
        for (values, mids) in [(&forward, &mid_f), (&reverse, &mid_r)] {
            for (k, model) in mids.iter().enumerate() {
                let lo = values.get(k).copied().unwrap_or(0.0);
                let hi = values.get(k + 1).copied().unwrap_or(0.0);
                interpolation_error = interpolation_error.max((model - 0.5 * (lo + hi)).abs());
            }
        }
        AxisTable {
            axis: self.axis,
            nominal: self.nominal.clone(),
            forward,
            reverse,
            interpolation_error,
        }
    }
}

impl AxisTable {
    /// The table's correction at `position` for direction `dir` (≥ 0 forward), interpolated
    /// linearly and held at the end values outside the table.
    pub fn correction(&self, position: f64, dir: f64) -> f64 {
        let values = if dir >= 0.0 {
            &self.forward
        } else {
            &self.reverse
        };
        let n = self.nominal.len().min(values.len());
        let (Some(&first), Some(&last)) =
            (self.nominal.first(), self.nominal.get(n.wrapping_sub(1)))
        else {
            return 0.0;
        };
        if position <= first {
            return values.first().copied().unwrap_or(0.0);
        }
        if position >= last {
            return values.get(n - 1).copied().unwrap_or(0.0);
        }
        let k = self
            .nominal
            .partition_point(|x| *x <= position)
            .saturating_sub(1);
        let at = |v: &[f64], i: usize| v.get(i).copied().unwrap_or(0.0);
        let (a, b) = (at(&self.nominal, k), at(&self.nominal, k + 1));
        let t = if b > a { (position - a) / (b - a) } else { 0.0 };
        at(values, k) + t * (at(values, k + 1) - at(values, k))
    }

    /// The LinuxCNC joint compensation file, `COMP_FILE_TYPE = 0`: one line per nominal
    /// position, `nominal forward reverse`, where forward and reverse are the positions the
    /// joint really reaches, without compensation, when commanded to the nominal one moving in
    /// the positive and in the negative direction (so the controller adds `nominal − forward`
    /// to its command). In `unit` (the machine units LinuxCNC is configured with). The loader
    /// reads lines of three numbers and stops at the first line that is not one, so the file
    /// holds nothing else: no header, no comments.
    pub fn linuxcnc(&self, unit: &Unit) -> String {
        let mut out = String::new();
        for ((p, f), r) in self.nominal.iter().zip(&self.forward).zip(&self.reverse) {
            let show = |si: f64| format_number(unit.from_si(si));
            out.push_str(&format!("{} {} {}\n", show(*p), show(p - f), show(p - r)));
        }
        out
    }
}

/// Twelve significant digits: well below a nanometre on any machine's travel, without the
/// binary noise of the shortest round-trip form.
fn format_number(v: f64) -> String {
    if v == 0.0 {
        return "0".to_string();
    }
    let text = format!("{:.*e}", 11, v);
    // Plain digits read more easily in a controller's file; `sscanf("%lf")` takes either.
    match text.parse::<f64>() {
        Ok(x) if x != 0.0 && (1e-4..1e9).contains(&x.abs()) => {
            let digits = (11 - x.abs().log10().floor() as i32).clamp(0, 15) as usize;
            let plain = format!("{x:.digits$}");
            let plain = plain.trim_end_matches('0').trim_end_matches('.');
            plain.to_string()
        }
        _ => text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_holds_the_ends_and_is_linear_between() {
        let t = AxisTable {
            axis: 0,
            nominal: vec![0.0, 1.0, 3.0],
            forward: vec![0.0, 2.0, 6.0],
            reverse: vec![1.0, 1.0, 1.0],
            interpolation_error: 0.0,
        };
        assert_eq!(t.correction(-1.0, 1.0), 0.0);
        assert_eq!(t.correction(0.5, 1.0), 1.0);
        assert_eq!(t.correction(2.0, 1.0), 4.0);
        assert_eq!(t.correction(9.0, 1.0), 6.0);
        assert_eq!(t.correction(2.0, -1.0), 1.0);
    }

    #[test]
    fn numbers_are_plain_and_exact_enough() {
        assert_eq!(format_number(100.0), "100");
        assert_eq!(format_number(-0.0125), "-0.0125");
        assert_eq!(format_number(99.987654321987), "99.987654322");
        assert_eq!(format_number(0.0), "0");
    }
}
