//! Duty cycles for `kin simulate --cycle`: a small language of spindle-speed segments and the
//! inputs they drive, sampled at a fixed interval (spec/cli.md, "Duty cycles").
//!
//! ```text
//! spindle T_spindle 2 K per 1000 rpm tau 40 min; room T_room 0.5 K period 24 h;
//! warmup 8000 rpm 2 h; steps 2000,4000,8000 rpm 30 min; stop 1 h
//! ```
//!
//! The physics of the generator: a spindle running at speed `s` dissipates heat at a rate that
//! grows with `s` (bearing friction); taken as proportional, the temperature rise `T` of the
//! structure near it follows the first-order response `dT/dt = (g·s − T)/τ` of a lumped heat
//! capacity with conduction to its surroundings (thesis eq. 3.41 with one mode): `g` the steady
//! rise per unit speed, `τ` the thermal time constant. Speed changes are taken as instantaneous,
//! so between changes `T` relaxes exponentially and is sampled exactly. The room follows a
//! sinusoid of the given amplitude and period (the daily cycle), starting at its mean.

use kin_compiler::ir::Machine;
use kin_compiler::units::{Dim, Unit};
use thiserror::Error;

/// A problem in a cycle's text, at a 1-based character column.
#[derive(Debug, Error, PartialEq)]
#[error("column {column}: {message}")]
pub struct CycleError {
    pub column: usize,
    pub message: String,
}

/// One segment of constant spindle speed (rev/s) lasting `duration` (s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub speed: f64,
    pub duration: f64,
}

/// An input driven by the spindle speed: steady value `gain · speed` (SI per rev/s), reached
/// with time constant `tau` (s).
#[derive(Debug, Clone, PartialEq)]
pub struct Spindle {
    pub input: usize,
    pub gain: f64,
    pub tau: f64,
}

/// An input following the room: `amplitude · sin(2πt/period)` about its neutral value.
#[derive(Debug, Clone, PartialEq)]
pub struct Room {
    pub input: usize,
    pub amplitude: f64,
    pub period: f64,
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct Cycle {
    pub segments: Vec<Segment>,
    pub spindles: Vec<Spindle>,
    pub rooms: Vec<Room>,
}

/// Longest cycle accepted: a year, far beyond any thermal test, so an absurd duration is named.
const MAX_DURATION: f64 = 3.2e7;

struct Words<'a> {
    words: Vec<(usize, &'a str)>,
    at: usize,
    end: usize,
}

impl<'a> Words<'a> {
    fn next(&mut self, what: &str) -> Result<(usize, &'a str), CycleError> {
        let w = self.words.get(self.at).copied();
        self.at += 1;
        w.ok_or_else(|| CycleError {
            column: self.end,
            message: format!("expected {what}"),
        })
    }

    fn number(&mut self, what: &str) -> Result<(usize, f64), CycleError> {
        let (c, w) = self.next(what)?;
        match w.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok((c, v)),
            _ => Err(CycleError {
                column: c,
                message: format!("`{w}`: expected {what}"),
            }),
        }
    }

    fn keyword(&mut self, k: &str) -> Result<(), CycleError> {
        let (c, w) = self.next(&format!("`{k}`"))?;
        if w == k {
            Ok(())
        } else {
            Err(CycleError {
                column: c,
                message: format!("`{w}`: expected `{k}`"),
            })
        }
    }

    /// A number and a unit of `dim`, in SI.
    fn quantity(&mut self, dim: Dim, what: &str) -> Result<f64, CycleError> {
        let (_, v) = self.number(what)?;
        let (c, u) = self.next(&format!("the unit of {what}"))?;
        let unit = Unit::parse(u)
            .ok()
            .filter(|x| x.dim == dim)
            .ok_or(CycleError {
                column: c,
                message: format!("`{u}`: expected a unit of {}", dim.describe()),
            })?;
        Ok(v * unit.scale)
    }

    fn duration(&mut self) -> Result<f64, CycleError> {
        let column = self.words.get(self.at).map_or(self.end, |w| w.0);
        let d = self.quantity(Dim::TIME, "a duration")?;
        if d > 0.0 && d <= MAX_DURATION {
            Ok(d)
        } else {
            Err(CycleError {
                column,
                message: "a duration must be positive and at most a year".into(),
            })
        }
    }

    /// Speeds in `rpm`, returned in rev/s.
    fn speeds(&mut self) -> Result<Vec<f64>, CycleError> {
        let (c, w) = self.next("a spindle speed")?;
        let mut out = Vec::new();
        let mut col = c;
        for part in w.split(',') {
            match part.parse::<f64>() {
                Ok(v) if (0.0..=1e6).contains(&v) => out.push(v / 60.0),
                _ => {
                    return Err(CycleError {
                        column: col,
                        message: format!(
                            "`{part}`: expected a spindle speed in rpm (0 to 1 000 000)"
                        ),
                    })
                }
            }
            col += part.chars().count() + 1;
        }
        self.keyword("rpm")?;
        Ok(out)
    }

    fn input(&mut self, m: &Machine) -> Result<usize, CycleError> {
        let (c, w) = self.next("an input of the machine")?;
        m.inputs.iter().position(|i| i.name == w).ok_or(CycleError {
            column: c,
            message: format!(
                "`{w}` is not an input of machine `{}` (its inputs: {})",
                m.name,
                m.inputs
                    .iter()
                    .map(|i| i.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        })
    }
}

/// Parses a cycle's text against the machine whose inputs it names.
pub fn parse(text: &str, m: &Machine) -> Result<Cycle, CycleError> {
    let mut cycle = Cycle::default();
    // Items are separated by `;` or line breaks; words by blanks. Columns count characters.
    let mut items: Vec<Vec<(usize, &str)>> = vec![Vec::new()];
    let mut word: Option<(usize, usize)> = None; // (column, start byte)
    let mut chars = 0usize;
    for (col, (b, ch)) in text.char_indices().enumerate() {
        chars = col + 1;
        let blank = ch.is_whitespace() || ch == ';';
        if blank {
            if let (Some((c, start)), Some(item)) = (word.take(), items.last_mut()) {
                item.push((c, text.get(start..b).unwrap_or("")));
            }
            if ch == ';' || ch == '\n' {
                items.push(Vec::new());
            }
        } else if word.is_none() {
            word = Some((col + 1, b));
        }
    }
    if let (Some((c, start)), Some(item)) = (word.take(), items.last_mut()) {
        item.push((c, text.get(start..).unwrap_or("")));
    }
    let end = chars + 1;
    for item in items.into_iter().filter(|i| !i.is_empty()) {
        let mut w = Words {
            words: item,
            at: 0,
            end,
        };
        let (c, head) = w.next("an item")?;
        match head {
            "warmup" | "run" => {
                let speeds = w.speeds()?;
                if speeds.len() != 1 {
                    return Err(CycleError {
                        column: c,
                        message: format!("`{head}` takes one speed; `steps` takes several"),
                    });
                }
                let duration = w.duration()?;
                cycle
                    .segments
                    .extend(speeds.iter().map(|&speed| Segment { speed, duration }));
            }
            "steps" => {
                let speeds = w.speeds()?;
                let duration = w.duration()?;
                cycle
                    .segments
                    .extend(speeds.iter().map(|&speed| Segment { speed, duration }));
            }
            "stop" => {
                let duration = w.duration()?;
                cycle.segments.push(Segment {
                    speed: 0.0,
                    duration,
                });
            }
            "spindle" => {
                let input = w.input(m)?;
                let dim = m
                    .inputs
                    .get(input)
                    .map_or(Dim::DIMENSIONLESS, |i| i.unit.dim);
                let gain = w.quantity(dim, "the steady-state change of the input")?;
                w.keyword("per")?;
                let speed = w.speeds()?;
                let per = speed.first().copied().unwrap_or(0.0);
                if speed.len() != 1 || !(per > 0.0) {
                    return Err(CycleError {
                        column: c,
                        message: "`per` takes one positive speed, e.g. `per 1000 rpm`".into(),
                    });
                }
                w.keyword("tau")?;
                let tau = w.duration()?;
                cycle.spindles.push(Spindle {
                    input,
                    gain: gain / per,
                    tau,
                });
            }
            "room" => {
                let input = w.input(m)?;
                let dim = m
                    .inputs
                    .get(input)
                    .map_or(Dim::DIMENSIONLESS, |i| i.unit.dim);
                let amplitude = w.quantity(dim, "the amplitude")?;
                w.keyword("period")?;
                let period = w.duration()?;
                cycle.rooms.push(Room {
                    input,
                    amplitude,
                    period,
                });
            }
            other => {
                return Err(CycleError {
                    column: c,
                    message: format!(
                        "`{other}`: expected an item: warmup, steps, stop, spindle or room"
                    ),
                })
            }
        }
        if let Some((c, extra)) = w.words.get(w.at) {
            return Err(CycleError {
                column: *c,
                message: format!("`{extra}`: expected `;` or the end of the cycle"),
            });
        }
    }
    if cycle.segments.is_empty() {
        return Err(CycleError {
            column: end,
            message: "the cycle has no segment (warmup, steps or stop)".into(),
        });
    }
    for (k, s) in cycle.spindles.iter().enumerate() {
        if cycle
            .spindles
            .iter()
            .skip(k + 1)
            .any(|t| t.input == s.input)
            || cycle.rooms.iter().any(|r| r.input == s.input)
        {
            return Err(CycleError {
                column: 1,
                message: format!(
                    "input `{}` is driven twice",
                    m.inputs.get(s.input).map_or("", |i| i.name.as_str())
                ),
            });
        }
    }
    Ok(cycle)
}

impl Cycle {
    pub fn duration(&self) -> f64 {
        self.segments.iter().map(|s| s.duration).sum()
    }

    /// The sampling instants `0, every, 2·every, …` up to the cycle's end (inclusive), and
    /// every input's value at each (SI; inputs the cycle does not drive at their neutral
    /// value: 0 for a rise, 20 °C for an absolute temperature).
    pub fn sample(&self, m: &Machine, every: f64) -> (Vec<f64>, Vec<Vec<f64>>) {
        let total = self.duration();
        let count = if every > 0.0 {
            (total / every + 1e-9).floor() as usize + 1
        } else {
            1
        };
        let times: Vec<f64> = (0..count).map(|k| k as f64 * every).collect();
        let mut inputs: Vec<Vec<f64>> = m
            .inputs
            .iter()
            .map(|i| {
                let neutral = if i.absolute && i.unit.dim == Dim::TEMPERATURE {
                    293.15
                } else {
                    0.0
                };
                vec![neutral; times.len()]
            })
            .collect();
        for s in &self.spindles {
            let Some(col) = inputs.get_mut(s.input) else {
                continue;
            };
            // Exact relaxation towards g·speed within each segment; the state carries over.
            let mut x = 0.0;
            let mut seg = self.segments.iter();
            let mut current = seg.next().copied();
            let mut seg_start = 0.0;
            let mut t_state = 0.0;
            for (slot, &t) in col.iter_mut().zip(&times) {
                while let Some(cs) = current {
                    if t <= seg_start + cs.duration {
                        break;
                    }
                    // Finish the segment.
                    let end = seg_start + cs.duration;
                    x = relax(x, s.gain * cs.speed, end - t_state, s.tau);
                    t_state = end;
                    seg_start = end;
                    current = seg.next().copied();
                }
                let target = current.map_or(0.0, |cs| s.gain * cs.speed);
                x = relax(x, target, t - t_state, s.tau);
                t_state = t;
                *slot += x;
            }
        }
        for r in &self.rooms {
            if let Some(col) = inputs.get_mut(r.input) {
                for (slot, &t) in col.iter_mut().zip(&times) {
                    *slot += r.amplitude * (std::f64::consts::TAU * t / r.period).sin();
                }
            }
        }
        (times, inputs)
    }
}

/// First-order relaxation of `x` towards the constant `target` over `dt` with time constant `tau`.
fn relax(x: f64, target: f64, dt: f64, tau: f64) -> f64 {
    if !(dt > 0.0) {
        return x;
    }
    target + (x - target) * libm::exp(-dt / tau)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn machine() -> Machine {
        let src = r#"machine m {
    task position
    units { length mm, angle deg, error um, tilt urad, time min, temperature degC }
    axis X prismatic along x range 0 mm .. 500 mm
    input T_spindle : temperature rise
    input T_room : temperature rise
    tool chain { X moving  tool t at (0, 0, 0) mm }
    workpiece chain { workpiece at (0, 0, 0) mm }
    errors { X.tx = lag(T_spindle, tau fit 30 min) * const }
}"#;
        match kin_compiler::compile(src).compiled {
            Some(c) => c.machine,
            None => panic!("test machine does not compile"),
        }
    }

    #[test]
    fn the_documented_example_parses() {
        let m = machine();
        let c = parse(
            "spindle T_spindle 2 K per 1000 rpm tau 40 min; room T_room 0.5 K period 24 h;\nwarmup 8000 rpm 2 h; steps 2000,4000,8000 rpm 30 min; stop 1 h",
            &m,
        )
        .expect("parses");
        assert_eq!(c.segments.len(), 5);
        assert!((c.duration() - 4.5 * 3600.0).abs() < 1e-9);
        assert!((c.segments[1].speed - 2000.0 / 60.0).abs() < 1e-12);
        assert!((c.spindles[0].gain - 2.0 / (1000.0 / 60.0)).abs() < 1e-12);
        assert!((c.spindles[0].tau - 2400.0).abs() < 1e-9);
        assert!((c.rooms[0].period - 86400.0).abs() < 1e-9);
    }

    #[test]
    fn errors_are_located() {
        let m = machine();
        let e = parse("warmup 8000 rpm 2 parsecs", &m).unwrap_err();
        assert_eq!(e.column, 19, "{e}");
        let e = parse("warmup 8000 rpm 2 h; spin 1 h", &m).unwrap_err();
        assert_eq!(e.column, 22, "{e}");
        assert!(e.message.contains("expected an item"));
        let e = parse("steps 2000,x,8000 rpm 30 min", &m).unwrap_err();
        assert_eq!(e.column, 12, "{e}");
        let e = parse("spindle T_bed 1 K per 1000 rpm tau 1 h; stop 1 h", &m).unwrap_err();
        assert_eq!(e.column, 9, "{e}");
        assert!(e.message.contains("T_spindle"));
        let e = parse("spindle T_spindle 1 K per 1000 rpm tau 1 h", &m).unwrap_err();
        assert!(e.message.contains("no segment"), "{e}");
        let e = parse("stop 1 h extra", &m).unwrap_err();
        assert_eq!(e.column, 10, "{e}");
        let e = parse("stop -1 h", &m).unwrap_err();
        assert_eq!(e.column, 6, "{e}");
    }

    #[test]
    fn the_spindle_temperature_is_the_exact_first_order_response() {
        // Closed form: a step to g·s at 0, held 2 h, then a stop: T = g·s(1 − e^{−t/τ}), then
        // decaying from its value at 2 h.
        let m = machine();
        let c = parse(
            "spindle T_spindle 2 K per 1000 rpm tau 40 min; warmup 6000 rpm 2 h; stop 1 h",
            &m,
        )
        .expect("parses");
        let (t, u) = c.sample(&m, 7.0 * 60.0);
        let (g, tau) = (12.0, 2400.0);
        let at2 = g * (1.0 - (-7200.0f64 / tau).exp());
        for (tk, uk) in t.iter().zip(&u[0]) {
            let want = if *tk <= 7200.0 {
                g * (1.0 - (-tk / tau).exp())
            } else {
                at2 * (-(tk - 7200.0) / tau).exp()
            };
            assert!((uk - want).abs() < 1e-9, "t {tk}: {uk} vs {want}");
        }
        assert!(u[1].iter().all(|&x| x == 0.0), "the room is not driven");
        assert!((t.last().copied().unwrap_or(0.0) - 10500.0).abs() < 1e-9);
    }
}
