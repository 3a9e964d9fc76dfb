//! Observation states from measurement rows: what the interpreter evaluates, row by row.
//!
//! Lag states are integrated here, per run in time order (spec/data.md), because they depend on
//! the history of a run rather than on one row.

use kin_compiler::ir::{Machine, Scalar, Var};
use thiserror::Error;

use crate::interp::{var_name, State};
use crate::lag;
use kin_data::data::{Pose, Rows};

#[derive(Debug, Error, PartialEq)]
pub enum StateError {
    #[error("the model uses `{column}`, but the file has no such column")]
    MissingColumn { column: String },
    #[error("line {line}: the model uses `{column}`, but this row leaves it empty")]
    EmptyCell { line: usize, column: String },
    #[error("the model uses a lag of `{input}`, which needs a `time` column")]
    NoTime { input: String },
}

/// Observation states of many rows, stored flat (one stride per quantity).
#[derive(Debug, Clone, Default)]
pub struct States {
    axes: usize,
    inputs: usize,
    lags: usize,
    q: Vec<f64>,
    input: Vec<f64>,
    lag: Vec<f64>,
    time: Vec<f64>,
    dirs: Vec<f64>,
    tool: Vec<usize>,
    tool_offset: Vec<Option<[f64; 3]>>,
    /// Source line of each row.
    pub line: Vec<usize>,
}

/// The direction columns of `n` rows held at one pose: each axis whose direction of motion the
/// model reads (a `backlash`, say) as reached moving in + (`+1`), the others absent. A pose a
/// duty cycle holds still has no motion of its own; + is the convention the tables and grids
/// of `kin compensate` use too (spec/cli.md).
pub fn held_directions(m: &Machine, n: usize) -> Vec<Option<Vec<f64>>> {
    let used = used_vars(m);
    (0..m.axes.len())
        .map(|a| used.contains(&Var::Direction(a)).then(|| vec![1.0; n]))
        .collect()
}

/// Every state variable the model reads.
pub fn used_vars(m: &Machine) -> Vec<Var> {
    fn walk(s: &Scalar, out: &mut Vec<Var>) {
        match s {
            Scalar::Num(_) => {}
            Scalar::Var(v) => out.push(*v),
            Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => walk(a, out),
            Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
                walk(a, out);
                walk(b, out);
            }
        }
    }
    let mut out = Vec::new();
    for t in m.errors.iter().flat_map(|e| &e.terms) {
        walk(&t.scale, &mut out);
        out.extend(t.factors.iter().map(|f| f.var));
    }
    for l in &m.lags {
        if !l.warmup {
            out.push(Var::Input(l.input));
        }
        out.push(Var::Time);
    }
    out.sort_by_key(|v| format!("{v:?}"));
    out.dedup();
    out
}

impl States {
    /// States of the rows of one pose of a file (a point file's pose, or one end of a length
    /// file), checking that every variable the model uses is there.
    pub fn new(m: &Machine, rows: &Rows, pose: &Pose, suffix: &str) -> Result<States, StateError> {
        let n = rows.len();
        let used = used_vars(m);
        let column_of = |v: Var| -> Option<&Vec<f64>> {
            match v {
                Var::Axis(a) => pose.axes.get(a),
                Var::Direction(a) => pose.dir.get(a)?.as_ref(),
                Var::Input(i) => rows.inputs.get(i)?.as_ref(),
                Var::Time => rows.time.as_ref(),
                Var::Lag(_) => None,
            }
        };
        let column_name = |v: Var| -> String {
            match v {
                Var::Axis(_) | Var::Direction(_) => format!("{}{suffix}", var_name(v, m)),
                _ => var_name(v, m),
            }
        };
        for &v in used.iter().chain(
            m.axes
                .iter()
                .enumerate()
                .map(|(a, _)| Var::Axis(a))
                .collect::<Vec<_>>()
                .iter(),
        ) {
            if matches!(v, Var::Lag(_)) {
                continue;
            }
            let Some(col) = column_of(v) else {
                if v == Var::Time {
                    // A warm-up needs `time` as such: the plain missing column says it.
                    if let Some(l) = m.lags.iter().find(|l| !l.warmup) {
                        return Err(StateError::NoTime {
                            input: m
                                .inputs
                                .get(l.input)
                                .map(|i| i.name.clone())
                                .unwrap_or_default(),
                        });
                    }
                }
                return Err(StateError::MissingColumn {
                    column: column_name(v),
                });
            };
            if let Some(row) = col.iter().position(|x| x.is_nan()) {
                return Err(StateError::EmptyCell {
                    line: rows.line.get(row).copied().unwrap_or(0),
                    column: column_name(v),
                });
            }
        }
        let axes = m.axes.len();
        let inputs = m.inputs.len();
        let mut states = States {
            axes,
            inputs,
            lags: m.lags.len(),
            q: gather(n, axes, |a| pose.axes.get(a)),
            input: gather(n, inputs, |i| rows.inputs.get(i).and_then(|c| c.as_ref())),
            lag: vec![0.0; n * m.lags.len()],
            time: rows.time.clone().unwrap_or_else(|| vec![0.0; n]),
            dirs: gather(n, axes, |a| pose.dir.get(a).and_then(|c| c.as_ref())),
            tool: rows.tool.clone(),
            tool_offset: (0..n).map(|r| rows.tool_offset_of(r)).collect(),
            line: rows.line.clone(),
        };
        let nonlinear: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        states.integrate_lags(m, rows, &nonlinear);
        Ok(states)
    }

    /// Recomputes the lag states for the given non-linear parameter values (time constants).
    pub fn integrate_lags(&mut self, m: &Machine, rows: &Rows, nonlinear: &[f64]) {
        self.integrate_lags_where(m, rows, nonlinear, |_| true);
    }

    /// [`States::integrate_lags`] for the lags `which` accepts (by index in `m.lags`) alone:
    /// the others keep their states.
    pub fn integrate_lags_where(
        &mut self,
        m: &Machine,
        rows: &Rows,
        nonlinear: &[f64],
        which: impl Fn(usize) -> bool,
    ) {
        let n = self.len();
        if !(0..m.lags.len()).any(&which) || n == 0 {
            return;
        }
        // Rows of a run are contiguous in time order within the run, but runs may interleave
        // in the file: collect each run's rows first.
        let mut runs: Vec<Vec<usize>> = Vec::new();
        let mut index: std::collections::HashMap<u32, usize> = std::collections::HashMap::new();
        for r in 0..n {
            let id = rows.run_of(r);
            let k = *index.entry(id).or_insert_with(|| {
                runs.push(Vec::new());
                runs.len() - 1
            });
            if let Some(run) = runs.get_mut(k) {
                run.push(r);
            }
        }
        let nl = self.lags;
        for (li, l) in m.lags.iter().enumerate().filter(|(li, _)| which(*li)) {
            for run in &runs {
                let times: Vec<f64> = run
                    .iter()
                    .map(|&r| self.time.get(r).copied().unwrap_or(0.0))
                    .collect();
                let u: Vec<f64> = run
                    .iter()
                    .map(|&r| {
                        self.input
                            .get(r * self.inputs + l.input)
                            .copied()
                            .unwrap_or(f64::NAN)
                    })
                    .collect();
                let mut x = vec![0.0; run.len()];
                lag::run(l, nonlinear, &times, &u, &mut x);
                for (&r, v) in run.iter().zip(x) {
                    if let Some(slot) = self.lag.get_mut(r * nl + li) {
                        *slot = v;
                    }
                }
            }
        }
    }

    pub fn len(&self) -> usize {
        self.line.len()
    }

    pub fn is_empty(&self) -> bool {
        self.line.is_empty()
    }

    /// The state of row `r`; an out-of-range row gives empty slices (rejected by the
    /// interpreter's size check).
    pub fn get(&self, r: usize) -> State<'_> {
        State {
            q: row_slice(&self.q, r, self.axes),
            inputs: row_slice(&self.input, r, self.inputs),
            lags: row_slice(&self.lag, r, self.lags),
            time: self.time.get(r).copied().unwrap_or(0.0),
            dirs: row_slice(&self.dirs, r, self.axes),
            tool: self.tool.get(r).copied().unwrap_or(0),
            tool_offset: self.tool_offset.get(r).copied().flatten(),
        }
    }
}

fn row_slice(v: &[f64], r: usize, stride: usize) -> &[f64] {
    v.get(r * stride..(r + 1) * stride).unwrap_or(&[])
}

/// Row-major `n × count` table from per-column data; NaN where a column is absent.
fn gather<'a>(n: usize, count: usize, column: impl Fn(usize) -> Option<&'a Vec<f64>>) -> Vec<f64> {
    let mut out = vec![f64::NAN; n * count];
    for k in 0..count {
        if let Some(col) = column(k) {
            for (r, x) in col.iter().enumerate().take(n) {
                if let Some(slot) = out.get_mut(r * count + k) {
                    *slot = *x;
                }
            }
        }
    }
    out
}

impl States {
    /// `n` states drawn uniformly over the declared ranges: axis positions, input ranges (or a
    /// plausible spread around a neutral value where none is declared), random directions of
    /// motion and tools; lags in steady state with their input. For identifiability on sampled
    /// states and for tests.
    pub fn sample(m: &Machine, n: usize, seed: u64) -> States {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let axes = m.axes.len();
        let inputs = m.inputs.len();
        // Capacity hints only: a product that overflows (an absurd `n` from a caller) reserves
        // nothing up front instead of panicking; the vectors still grow as rows are drawn.
        let hint = |width: usize| n.checked_mul(width).unwrap_or(0);
        let mut s = States {
            axes,
            inputs,
            lags: m.lags.len(),
            q: Vec::with_capacity(hint(axes)),
            input: Vec::with_capacity(hint(inputs)),
            lag: Vec::with_capacity(hint(m.lags.len())),
            time: (0..n).map(|r| r as f64).collect(),
            dirs: Vec::with_capacity(hint(axes)),
            tool: Vec::with_capacity(n),
            tool_offset: vec![None; n],
            line: (1..=n).collect(),
        };
        for _ in 0..n {
            for a in &m.axes {
                s.q.push(rng.random_range(a.range[0]..=a.range[1]));
                s.dirs.push(if rng.random_bool(0.5) { 1.0 } else { -1.0 });
            }
            let row: Vec<f64> = m
                .inputs
                .iter()
                .map(|i| {
                    // Without a declared range: a plausible spread around a neutral value.
                    let (lo, hi) = match i.unit.dim {
                        _ if i.range.is_some() => {
                            i.range.map(|r| (r[0], r[1])).unwrap_or((0.0, 1.0))
                        }
                        d if d == kin_compiler::units::Dim::TEMPERATURE && i.absolute => {
                            (291.15, 295.15)
                        }
                        d if d == kin_compiler::units::Dim::TEMPERATURE => (0.0, 4.0),
                        d if d == kin_compiler::units::Dim::FORCE => (0.0, 1000.0),
                        // A spindle at rest up to 12 000 rpm, a feed up to 10 m/min, up to
                        // 10 kW: where machine tools run.
                        d if d == kin_compiler::units::Dim::SPEED => (0.0, 1256.6),
                        d if d == kin_compiler::units::Dim::VELOCITY => (0.0, 0.1667),
                        d if d == kin_compiler::units::Dim::POWER => (0.0, 10_000.0),
                        _ => (0.0, 1.0),
                    };
                    rng.random_range(lo..=hi)
                })
                .collect();
            for l in &m.lags {
                s.lag
                    .push(l.steady(row.get(l.input).copied().unwrap_or(0.0)));
            }
            s.input.extend(row);
            s.tool.push(rng.random_range(0..m.tools.len().max(1)));
        }
        s
    }

    /// Overrides the input values of every row (e.g. to neutralise fixed terms in a test).
    pub fn set_input(&mut self, input: usize, value: f64) {
        let stride = self.inputs;
        for r in 0..self.len() {
            if let Some(slot) = self.input.get_mut(r * stride + input) {
                *slot = value;
            }
        }
    }
}
