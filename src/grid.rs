//! `--grid SPEC` of `kin compensate`: the commanded poses on a regular grid, parsed into a
//! [`Grid`] (kin-machine's, which gives the poses file it stands for).
//!
//! `SPEC` is a comma-separated list of `NAME=VALUE` or `NAME=FROM:TO:STEP`, where NAME is an
//! axis (in the model's length or angle unit) or an input (in its declared unit), plus
//! `dir_AXIS=+1|-1` and `tool=NAME`. A range runs FROM, FROM+STEP, … and always ends at TO.

use kin_compiler::ir::{JointKind, Machine, Var};
pub(crate) use kin_machine::grid::Grid;

/// At most this many grid points in all (every pose is held in memory and compensated).
pub const MAX_POINTS: usize = 10_000_000;

/// The largest magnitude of a grid value in its unit: a thousand kilometres in mm, some 2.8
/// million turns in degrees. Beyond any machine, it keeps absurd values (printed as 300
/// digits, or turning a continuous axis through rounding noise) out of the poses.
const MAX_VALUE: f64 = 1e9;

fn number(text: &str, what: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.abs() <= MAX_VALUE => Ok(v),
        Ok(v) if v.is_finite() => Err(format!(
            "`{text}` in `{what}` is beyond ±1e9, larger than any axis or input of a machine"
        )),
        _ => Err(format!("`{text}` in `{what}` is not a finite number")),
    }
}

/// The values FROM, FROM+STEP, … TO (in the spec's unit).
fn range(text: &str, item: &str) -> Result<Vec<f64>, String> {
    let parts: Vec<&str> = text.split(':').collect();
    match parts.as_slice() {
        [v] => Ok(vec![number(v, item)?]),
        [from, to, step] => {
            let (from, to, step) = (number(from, item)?, number(to, item)?, number(step, item)?);
            if step <= 0.0 || to < from {
                return Err(format!(
                    "`{item}`: a range is FROM:TO:STEP with FROM ≤ TO and STEP > 0"
                ));
            }
            let span = to - from;
            // Steps that land on TO up to rounding count as landing on it.
            let steps = (span / step * (1.0 + 1e-12)).floor();
            if steps >= MAX_POINTS as f64 {
                return Err(format!(
                    "`{item}` has more than {MAX_POINTS} points: a larger STEP"
                ));
            }
            let mut values: Vec<f64> = (0..=steps as usize)
                .map(|k| from + step * k as f64)
                .collect();
            if let Some(last) = values.last_mut() {
                if (to - *last).abs() <= 1e-9 * span.max(step) {
                    *last = to;
                } else {
                    values.push(to);
                }
            }
            Ok(values)
        }
        _ => Err(format!(
            "`{item}`: give a value or FROM:TO:STEP (e.g. X=0:500:50)"
        )),
    }
}

/// Parses `spec` for machine `m`; a problem is described for the user.
pub fn parse(spec: &str, m: &Machine) -> Result<Grid, String> {
    let mut values: Vec<Option<Vec<f64>>> = vec![None; m.axes.len()];
    let mut dirs = vec![1.0; m.axes.len()];
    let mut inputs: Vec<Option<f64>> = vec![None; m.inputs.len()];
    let mut tool = 0;
    for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let Some((name, value)) = item.split_once('=') else {
            return Err(format!("`{item}` is not NAME=VALUE or NAME=FROM:TO:STEP"));
        };
        let (name, value) = (name.trim(), value.trim());
        if name == "tool" {
            tool = m
                .tools
                .iter()
                .position(|t| t.name == value)
                .ok_or_else(|| {
                    let names: Vec<&str> = m.tools.iter().map(|t| t.name.as_str()).collect();
                    format!(
                        "`{item}`: the machine has no tool `{value}` (it has {})",
                        names.join(", ")
                    )
                })?;
        } else if let Some(axis) = name.strip_prefix("dir_") {
            let a = m
                .axes
                .iter()
                .position(|x| x.name == axis)
                .ok_or_else(|| format!("`{item}`: the machine has no axis `{axis}`"))?;
            dirs[a] = match value {
                "+1" | "1" => 1.0,
                "-1" => -1.0,
                _ => return Err(format!("`{item}`: a direction is +1 or -1")),
            };
        } else if let Some(a) = m.axes.iter().position(|x| x.name == name) {
            let axis = &m.axes[a];
            let unit = match axis.kind {
                JointKind::Prismatic => &m.units.length,
                JointKind::Revolute => &m.units.angle,
            };
            if values[a].is_some() {
                return Err(format!("`{item}`: axis {name} is given twice"));
            }
            let si: Vec<f64> = range(value, item)?
                .into_iter()
                .map(|v| unit.as_difference().to_si(v))
                .collect();
            let [lo, hi] = axis.range;
            let slack = 1e-9 * (hi - lo).abs();
            if !axis.continuous {
                if let Some(bad) = si
                    .iter()
                    .find(|v| !(**v >= lo - slack && **v <= hi + slack))
                {
                    let u = unit.as_difference();
                    return Err(format!(
                        "`{item}`: {} {} is outside the range of axis {name}, {} .. {} {}",
                        u.from_si(*bad),
                        unit.name,
                        u.from_si(lo),
                        u.from_si(hi),
                        unit.name
                    ));
                }
            }
            values[a] = Some(si);
        } else if let Some(i) = m.inputs.iter().position(|x| x.name == name) {
            let input = &m.inputs[i];
            let v = number(value, item)?;
            let unit = if input.absolute {
                input.unit.as_absolute()
            } else {
                input.unit.as_difference()
            };
            inputs[i] = Some(unit.to_si(v));
        } else {
            return Err(format!(
                "`{item}`: `{name}` is no axis, input, `dir_AXIS` or `tool` of machine `{}`",
                m.name
            ));
        }
    }
    let mut out = Vec::with_capacity(m.axes.len());
    for (axis, v) in m.axes.iter().zip(values) {
        match v {
            Some(v) => out.push(v),
            None if axis.continuous || (axis.range[0] <= 0.0 && axis.range[1] >= 0.0) => {
                out.push(vec![0.0])
            }
            None => {
                return Err(format!(
                "axis {} is not in the grid and 0 is outside its range: give it (e.g. {}=VALUE)",
                axis.name, axis.name
            ))
            }
        }
    }
    let used = kin_model::states::used_vars(m);
    for (i, input) in m.inputs.iter().enumerate() {
        if used.contains(&Var::Input(i)) && inputs.get(i).copied().flatten().is_none() {
            return Err(format!(
                "the model uses input `{}`: give its value in the grid (e.g. {}=0)",
                input.name, input.name
            ));
        }
    }
    let grid = Grid {
        values: out,
        dirs,
        inputs,
        tool,
    };
    match grid.count() {
        Some(n) if n <= MAX_POINTS => Ok(grid),
        _ => Err(format!(
            "the grid has more than {MAX_POINTS} points: larger steps, or fewer axes ranged"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_range_ends_at_to_whatever_the_step() {
        assert_eq!(range("0:10:5", "X").unwrap(), vec![0.0, 5.0, 10.0]);
        assert_eq!(range("0:10:4", "X").unwrap(), vec![0.0, 4.0, 8.0, 10.0]);
        assert_eq!(range("0:0.3:0.1", "X").unwrap().len(), 4);
        assert_eq!(range("7", "X").unwrap(), vec![7.0]);
        assert!(range("10:0:1", "X").is_err());
        assert!(range("0:10:0", "X").is_err());
        assert!(range("0:1e300:1e-300", "X").is_err());
        assert!(range("0:nan:1", "X").is_err());
    }

    /// A value beyond any machine is refused with the bound, in the user's words (it used to
    /// be echoed back as a 309-digit number).
    #[test]
    fn absurd_values_are_refused_with_the_bound() {
        let e = range("1e308", "X=1e308").unwrap_err();
        assert!(e.contains("±1e9") && e.len() < 120, "{e}");
        let e = range("0:2e9:1e8", "X=0:2e9:1e8").unwrap_err();
        assert!(e.contains("±1e9"), "{e}");
        assert_eq!(range("-1e9", "C").unwrap(), vec![-1e9]);
    }
}
