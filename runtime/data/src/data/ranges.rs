//! Rows outside the machine's declared ranges. A model is fitted, and its splines' knots are
//! placed, over an axis's declared range; a pose beyond it is an extrapolation (a spline's end
//! piece continued, a harmonic over a range never sampled), and on a real machine usually a typo
//! in the file's unit or a file of another machine. Commands read such rows as they are and say
//! so, once per axis or input, with the first row that shows it.

use kin_compiler::ir::{JointKind, Machine, Var};
use kin_compiler::units::Unit;

use super::Observations;

/// Whether `v` lies in `range`, allowing for the rounding of a unit conversion at its ends (a
/// file in inches of a machine declared in mm reaches the end of the range to ~1e-16).
pub fn within(range: [f64; 2], v: f64) -> bool {
    let [lo, hi] = range;
    let slack = 1e-9 * (hi - lo).abs().max(1e-12);
    v >= lo - slack && v <= hi + slack
}

/// One axis or input whose values leave its declared range in some rows.
#[derive(Debug, Clone, PartialEq)]
pub struct OutOfRange {
    /// The column's name in the file (`X`, `X_2` for the second end of a length, `T_room`).
    pub column: String,
    /// The declared range and the values below in `unit`.
    pub unit: String,
    pub range: [f64; 2],
    /// Rows with a value outside the range, of `rows` read.
    pub outside: usize,
    pub rows: usize,
    /// The first such row: its line in the file and its value.
    pub first_line: usize,
    pub first: f64,
    /// The value farthest outside the range.
    pub farthest: f64,
}

impl std::fmt::Display for OutOfRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [lo, hi] = self.range;
        write!(
            f,
            "{} of {} rows put {} outside its declared range {} .. {} {} (first at line {}: {} {}; farthest {} {}): the model is extrapolated there",
            self.outside,
            self.rows,
            self.column,
            lo,
            hi,
            self.unit,
            self.first_line,
            self.first,
            self.unit,
            self.farthest,
            self.unit
        )
    }
}

/// Every axis (continuous revolute axes excepted) and every input with a declared range whose
/// values leave it, in the machine's order. Empty input cells (NaN) are not values.
pub fn outside(m: &Machine, obs: &Observations) -> Vec<OutOfRange> {
    let (rows, poses): (_, Vec<(&super::Pose, &str)>) = match obs {
        Observations::Points(p) => (&p.rows, vec![(&p.pose, "")]),
        Observations::Lengths(l) => (&l.rows, vec![(&l.poses[0], "_1"), (&l.poses[1], "_2")]),
    };
    let mut found = Vec::new();
    for (pose, suffix) in &poses {
        for (a, axis) in m.axes.iter().enumerate() {
            if axis.continuous {
                continue;
            }
            let unit = match axis.kind {
                JointKind::Prismatic => &m.units.length,
                JointKind::Revolute => &m.units.angle,
            };
            let values = (0..rows.len()).filter_map(|r| rows.value(pose, Var::Axis(a), r));
            let column = format!("{}{suffix}", axis.name);
            found.extend(scan(column, axis.range, unit, values, &rows.line));
        }
    }
    if let Some((pose, _)) = poses.first() {
        for (i, input) in m.inputs.iter().enumerate() {
            let Some(range) = input.range else { continue };
            let values = (0..rows.len()).filter_map(|r| rows.value(pose, Var::Input(i), r));
            found.extend(scan(
                input.name.clone(),
                range,
                &input.unit,
                values,
                &rows.line,
            ));
        }
    }
    found
}

fn scan(
    column: String,
    range: [f64; 2],
    unit: &Unit,
    values: impl Iterator<Item = f64>,
    lines: &[usize],
) -> Option<OutOfRange> {
    let mut out: Option<OutOfRange> = None;
    let mut rows = 0;
    let mut worst = 0.0;
    for (r, v) in values.enumerate() {
        rows += 1;
        if v.is_nan() || within(range, v) {
            continue;
        }
        let beyond = (range[0] - v).max(v - range[1]);
        let o = out.get_or_insert_with(|| OutOfRange {
            column: column.clone(),
            unit: unit.name.clone(),
            range: [unit.from_si(range[0]), unit.from_si(range[1])],
            outside: 0,
            rows: 0,
            first_line: lines.get(r).copied().unwrap_or(0),
            first: unit.from_si(v),
            farthest: unit.from_si(v),
        });
        o.outside += 1;
        if beyond > worst {
            worst = beyond;
            o.farthest = unit.from_si(v);
        }
    }
    if let Some(o) = out.as_mut() {
        o.rows = rows;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{read, ReadOptions};

    const MODEL: &str = "machine m {
    task measure
    units { length mm, angle deg, error um, tilt urad, temperature degC }
    axis X prismatic along x range 0 mm .. 100 mm
    axis C revolute about z range -30 deg .. 30 deg
    axis S revolute about z continuous
    input T_room : temperature absolute range 15 degC .. 25 degC
    workpiece chain { workpiece at (0, 0, 0) mm }
    tool chain {
        X moving at (0, 0, 0) mm
        C moving at (0, 0, 0) mm
        S moving at (0, 0, 0) mm
        tool t at (0, 0, 0) mm
    }
    errors {
        X.tx = spline(X, knots 3)
    }
}";

    fn machine() -> Machine {
        let out = kin_compiler::compile(MODEL);
        match out.compiled {
            Some(c) => c.machine,
            None => panic!("{:?}", out.diagnostics),
        }
    }

    fn read_text(text: &str, m: &Machine) -> Observations {
        match read(
            text.as_bytes(),
            std::path::Path::new("p.csv"),
            m,
            &ReadOptions::default(),
        ) {
            Ok(o) => o,
            Err(e) => panic!("{e}"),
        }
    }

    #[test]
    fn rows_outside_an_axis_or_input_range_are_counted_with_the_first_line() {
        let m = machine();
        let text = "X [mm],C [deg],S [deg],T_room [degC],ex [um]\n\
                    50,0,400,20,1\n\
                    100,30,-720,25,1\n\
                    120,0,0,20,1\n\
                    -5,-31,0,,1\n\
                    130,0,0,30,1\n";
        let obs = read_text(text, &m);
        let found = outside(&m, &obs);
        let names: Vec<&str> = found.iter().map(|o| o.column.as_str()).collect();
        // The ends of a range are inside; a continuous axis has no range; an empty cell is no value.
        assert_eq!(names, ["X", "C", "T_room"], "{found:?}");
        let x = &found[0];
        assert_eq!((x.outside, x.rows, x.first_line), (3, 5, 4));
        assert_eq!((x.first, x.farthest), (120.0, 130.0));
        assert!((found[1].first - -31.0).abs() < 1e-9, "{:?}", found[1]);
        assert_eq!(found[2].first_line, 6);
        assert!(x
            .to_string()
            .contains("3 of 5 rows put X outside its declared range 0 .. 100 mm"));
    }

    #[test]
    fn a_file_inside_the_ranges_says_nothing() {
        let m = machine();
        let text = "X [in],C [deg],S [deg],ex [um]\n0,-30,0,1\n3.937007874015748,30,9,1\n";
        let obs = read_text(text, &m);
        assert!(outside(&m, &obs).is_empty(), "{:?}", outside(&m, &obs));
    }
}
