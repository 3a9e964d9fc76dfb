//! A hand-written, hand-optimised evaluator of `examples/milling_5axis.kin`: the yardstick the
//! JIT is measured against (issue 4). It computes the error and the full 6 × 173 β-Jacobian the
//! interpreter computes (the tests check agreement to 1e-12), written as one would write it in C
//! for this one machine:
//!
//! * the kinematics in closed form: the workpiece chain Y, X, A, C has only fixed frames and
//!   axis-aligned joints and the tool chain one moving Z, so `M = R(wr→base) = R_z(−c)·R_x(−a)`
//!   and every origin is a few additions; the F-matrices (eq. 2.27/2.28 in wr axes) of Y, X, A,
//!   Z and the tool share `M`, C's is `R_z(−c)`;
//! * each basis evaluated once (Y.rx, Y.ry and Y.rz share one spline), by a routine specialised
//!   to its degree and knot count, branch-free (`max(s − t, 0)²` for a truncated power), with the
//!   knots, trends and α's read from the compiled model;
//! * the coefficient layout fixed at compile time (checked against the model when built), the
//!   Jacobian a fixed-size array, so every store has a constant offset and no bounds check;
//!   every entry is written on every call, structural zeros included, as the JIT does.
//!
//! [`Trig::Exact`] takes `libm::sincos` of every angle the interpreter takes a sine of (the same
//! numbers, 9 calls per pose); [`Trig::Recurrence`] is what one would write without that
//! constraint: harmonics by angle addition from one `sincos`, 4 calls per pose, agreeing to
//! ~1e-14 instead of bit for bit.
//!
//! [`Baseline::new`] refuses any other machine (or a changed example) with [`NotTheExample`],
//! so `kin bench` can offer the comparison exactly when it applies.

use kin_compiler::basis::{Basis, Detrend, Power, Wavelength};
use kin_compiler::ir::{Component, FrameKind, FrameRef, JointKind, Machine, Scalar, Var};

use kin_model::interp::State;

/// The machine is not `examples/milling_5axis.kin` as the baseline was written for: what differs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("not the 5-axis example the baseline was written for: {0}")]
pub struct NotTheExample(pub String);

/// Returns [`NotTheExample`] unless the condition holds.
macro_rules! ensure {
    ($cond:expr, $($msg:tt)+) => {
        if !$cond {
            return Err(NotTheExample(format!($($msg)+)));
        }
    };
}

/// Number of coefficients of the example.
pub const N: usize = 173;

/// How the sines and cosines of the C harmonics are obtained.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Trig {
    Exact,
    Recurrence,
}

/// A quadratic spline with `c = 1` (eq. 3.2–3.3): `s, s², (s − t_k)₊²`, optionally without `s`
/// and detrended by a line (straightness, eq. 3.4–3.8) or by `cos, sin` (eq. 3.9).
#[derive(Clone, Copy, Debug)]
struct Quad<const M: usize> {
    lo: f64,
    span: f64,
    knots: [f64; M],
    /// Trend of every function (zero when not detrended).
    trend: [[f64; 2]; 10],
}

#[derive(Clone, Copy, Debug)]
struct Periodic2 {
    tau: f64,
    knots: [f64; 2],
    alpha: [[f64; 2]; 2],
}

pub struct Baseline {
    trig: Trig,
    s_y: [f64; 3],
    s_x: [f64; 3],
    s_a: [f64; 3],
    s_c: [f64; 3],
    s_z: [f64; 3],
    tools: Vec<[f64; 3]>,
    y_ty: Quad<4>,
    y_per: Periodic2,
    y_str: Quad<3>,
    y_rot: Quad<3>,
    x_load: Quad<2>,
    x_tx: Quad<5>,
    x_per: Periodic2,
    x_str: Quad<4>,
    x_rot: Quad<3>,
    z_tz: (f64, f64, [f64; 4]),
    z_str: Quad<3>,
    z_rot: Quad<2>,
    a_lo: f64,
    a_span: f64,
    a_sp2: Quad<2>,
    a_sp3: Quad<3>,
    c_rev: Quad<6>,
    c_mid: f64,
    y_scale: Scalar,
    y_load: Scalar,
}

fn knots_of<const M: usize>(functions: &[Power]) -> Result<[f64; M], NotTheExample> {
    let knots: Vec<f64> = functions.iter().filter_map(|p| p.knot).collect();
    let count = knots.len();
    knots
        .try_into()
        .map_err(|_| NotTheExample(format!("{count} knots where {M} were expected")))
}

/// Reads a `spline(…)`/`straightness(…)` factor of degree 2, smooth 1 with `M` knots.
fn quad<const M: usize>(basis: &Basis, detrend: Detrend) -> Result<Quad<M>, NotTheExample> {
    let Basis::Spline {
        lo,
        hi,
        degree: 2,
        smooth: 1,
        detrend: d,
        functions,
        ..
    } = basis
    else {
        return Err(NotTheExample(format!(
            "expected a quadratic spline, got {basis:?}"
        )));
    };
    ensure!(
        *d == detrend,
        "detrending {d:?} where {detrend:?} was expected"
    );
    let first = if detrend == Detrend::Line { 2 } else { 1 };
    let expect: Vec<(Option<()>, u32)> = (first..=2)
        .map(|p| (None, p))
        .chain((0..M).map(|_| (Some(()), 2)))
        .collect();
    let got: Vec<(Option<()>, u32)> = functions
        .iter()
        .map(|f| (f.g.knot.map(|_| ()), f.g.power))
        .collect();
    ensure!(
        got == expect,
        "function layout {got:?}, expected {expect:?}"
    );
    let mut trend = [[0.0; 2]; 10];
    for (t, f) in trend.iter_mut().zip(functions) {
        *t = f.trend;
    }
    Ok(Quad {
        lo: *lo,
        span: hi - lo,
        knots: knots_of(&functions.iter().map(|f| f.g).collect::<Vec<_>>())?,
        trend,
    })
}

fn periodic2(basis: &Basis) -> Result<Periodic2, NotTheExample> {
    let Basis::Periodic {
        wavelength: Wavelength::Fixed(tau),
        phase,
        degree: 2,
        smooth: 1,
        functions,
        ..
    } = basis
    else {
        return Err(NotTheExample(format!(
            "expected a periodic term, got {basis:?}"
        )));
    };
    ensure!(*phase == 0.0, "a periodic term with a phase");
    let alpha = |f: &kin_compiler::basis::PeriodicFunction| -> Option<[f64; 2]> {
        (f.g.power == 2 && f.g.knot.is_some())
            .then(|| f.alpha.as_slice().try_into().ok())
            .flatten()
    };
    let [Some(a0), Some(a1)] = [
        functions.first().and_then(alpha),
        functions.get(1).and_then(alpha),
    ] else {
        return Err(NotTheExample(
            "the periodic terms have another layout".into(),
        ));
    };
    ensure!(
        functions.len() == 2,
        "{} periodic functions where 2 were expected",
        functions.len()
    );
    Ok(Periodic2 {
        tau: *tau,
        knots: knots_of(&functions.iter().map(|f| f.g).collect::<Vec<_>>())?,
        alpha: [a0, a1],
    })
}

/// `max(u − t, 0)²`: `(u − t)₊²` without a branch on the data (random poses would mispredict
/// an `if u > t` half the time); the same number, since `u > t` exactly when `u − t > 0`.
#[inline(always)]
fn tp2(u: f64, t: f64) -> f64 {
    let d = (u - t).max(0.0);
    d * d
}

impl<const M: usize> Quad<M> {
    #[inline(always)]
    fn s(&self, x: f64) -> f64 {
        (x - self.lo) / self.span
    }

    /// `s, s², (s − t_k)₊²`: `M + 2` values.
    #[inline(always)]
    fn plain<const K: usize>(&self, x: f64) -> [f64; K] {
        let s = self.s(x);
        let mut out = [0.0; K];
        out[0] = s;
        out[1] = s * s;
        for k in 0..M {
            out[2 + k] = tp2(s, self.knots[k]);
        }
        out
    }

    /// Straightness: `g − (t0 + t1·s)` for `g = s², (s − t_k)₊²`: `M + 1` values.
    #[inline(always)]
    fn straight<const K: usize>(&self, x: f64) -> [f64; K] {
        let s = self.s(x);
        let mut out = [0.0; K];
        let t = &self.trend;
        out[0] = s * s - (t[0][0] + t[0][1] * s);
        for k in 0..M {
            out[1 + k] = tp2(s, self.knots[k]) - (t[1 + k][0] + t[1 + k][1] * s);
        }
        out
    }

    /// Once-per-revolution removed (eq. 3.9): `g − t0·cos(x − m) − t1·sin(x − m)`.
    #[inline(always)]
    fn no_rev<const K: usize>(&self, x: f64, cos: f64, sin: f64) -> [f64; K] {
        let g: [f64; K] = self.plain(x);
        let mut out = [0.0; K];
        for k in 0..K {
            out[k] = g[k] - self.trend[k][0] * cos - self.trend[k][1] * sin;
        }
        out
    }
}

impl Periodic2 {
    /// `v(w) = (w − t)₊² − w·(α1 + w·α2)` (eq. 3.12–3.13).
    #[inline(always)]
    fn values(&self, x: f64) -> [f64; 2] {
        let y = x / self.tau;
        let mut w = y - y.floor();
        if w >= 1.0 {
            w = 0.0;
        }
        let v = |k: usize| tp2(w, self.knots[k]) - (self.alpha[k][1] * w + self.alpha[k][0]) * w;
        [v(0), v(1)]
    }
}

fn scalar(s: &Scalar, st: &State) -> f64 {
    match s {
        Scalar::Num(x) => *x,
        Scalar::Var(Var::Axis(i)) => st.q[*i],
        Scalar::Var(Var::Input(i)) => st.inputs[*i],
        Scalar::Var(Var::Lag(i)) => st.lags[*i],
        Scalar::Var(Var::Direction(i)) => st.dirs[*i],
        Scalar::Var(Var::Time) => st.time,
        Scalar::Neg(a) => -scalar(a, st),
        Scalar::Add(a, b) => scalar(a, st) + scalar(b, st),
        Scalar::Sub(a, b) => scalar(a, st) - scalar(b, st),
        Scalar::Mul(a, b) => scalar(a, st) * scalar(b, st),
        Scalar::Div(a, b) => scalar(a, st) / scalar(b, st),
        Scalar::Sin(a) => libm::sin(scalar(a, st)),
        Scalar::Cos(a) => libm::cos(scalar(a, st)),
    }
}

/// Writes a translation component's block (rows 0–2: `col·v`, rows 3–5: zero, the first
/// `rows` of them, none without `store`) from coefficient `j0` on and returns `Σ v·β`. Always
/// inlined into a caller whose `rows` and `store` are constants, so the tests fold away.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn put_t<const K: usize>(
    jac: &mut [f64],
    rows: usize,
    store: bool,
    beta: &[f64; N],
    j0: usize,
    col: &[f64; 3],
    v: &[f64; K],
) -> f64 {
    let mut value = 0.0;
    for (k, &vk) in v.iter().enumerate() {
        let j = j0 + k;
        if store {
            jac[j] = col[0] * vk;
            jac[N + j] = col[1] * vk;
            jac[2 * N + j] = col[2] * vk;
            if rows > 3 {
                jac[3 * N + j] = 0.0;
                jac[4 * N + j] = 0.0;
                jac[5 * N + j] = 0.0;
            }
        }
        value += vk * beta[j];
    }
    value
}

/// As [`put_t`] for a rotation component (six rows).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn put_r<const K: usize>(
    jac: &mut [f64],
    rows: usize,
    store: bool,
    beta: &[f64; N],
    j0: usize,
    col: &[f64; 6],
    v: &[f64; K],
) -> f64 {
    let mut value = 0.0;
    for (k, &vk) in v.iter().enumerate() {
        let j = j0 + k;
        if store {
            for (r, c) in col.iter().enumerate().take(rows) {
                jac[r * N + j] = c * vk;
            }
        }
        value += vk * beta[j];
    }
    value
}

#[inline(always)]
fn cat<const A: usize, const B: usize, const C: usize>(a: [f64; A], b: [f64; B]) -> [f64; C] {
    let mut out = [0.0; C];
    out[..A].copy_from_slice(&a);
    out[A..].copy_from_slice(&b);
    out
}

/// `e^{i(a+b)}` from `e^{ia}`, `e^{ib}` as (sin, cos).
#[inline(always)]
fn add_angles(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    (a.0 * b.1 + a.1 * b.0, a.1 * b.1 - a.0 * b.0)
}

impl Baseline {
    /// Reads the tables of `m`, which must be the 5-axis example: the layout is checked and
    /// anything else is refused (this is a baseline for one machine, not an engine).
    pub fn new(m: &Machine, trig: Trig) -> Result<Baseline, NotTheExample> {
        ensure!(
            m.coefficients.len() == N,
            "{} coefficients, not {N}",
            m.coefficients.len()
        );
        let names: Vec<&str> = m.axes.iter().map(|a| a.name.as_str()).collect();
        ensure!(names == ["Y", "X", "Z", "A", "C"], "axes {names:?}");
        let dirs: Vec<([f64; 3], JointKind, bool)> = m
            .axes
            .iter()
            .map(|a| (a.direction, a.kind, a.continuous))
            .collect();
        ensure!(
            dirs == [
                ([0.0, -1.0, 0.0], JointKind::Prismatic, false),
                ([-1.0, 0.0, 0.0], JointKind::Prismatic, false),
                ([0.0, 0.0, 1.0], JointKind::Prismatic, false),
                ([1.0, 0.0, 0.0], JointKind::Revolute, false),
                ([0.0, 0.0, 1.0], JointKind::Revolute, true),
            ],
            "axis directions {dirs:?}"
        );
        let wp: Vec<usize> = m.workpiece_chain.iter().map(|e| e.axis).collect();
        ensure!(wp == [0, 1, 3, 4], "workpiece chain {wp:?}");
        ensure!(
            m.workpiece_chain
                .iter()
                .all(|e| e.frame == FrameKind::Fixed && e.shape.rotation == [0.0; 3]),
            "a moving or rotated workpiece-chain frame"
        );
        let tool_chain: Vec<(usize, FrameKind)> =
            m.tool_chain.iter().map(|e| (e.axis, e.frame)).collect();
        ensure!(
            tool_chain == [(2, FrameKind::Moving)],
            "tool chain {tool_chain:?}"
        );
        ensure!(
            m.tools.iter().all(|t| t.offset.rotation == [0.0; 3]),
            "a rotated tool"
        );
        let tools: Vec<&str> = m.tools.iter().map(|t| t.name.as_str()).collect();
        ensure!(
            tools.len() == 2 && tools.get(1) == Some(&"probe"),
            "tools {tools:?}"
        );
        ensure!(
            (m.workpiece.translation, m.workpiece.rotation) == ([0.0; 3], [0.0; 3]),
            "the workpiece offset"
        );

        // The layout: (frame, component, first coefficient, count, variable) of every term.
        let layout: Vec<(FrameRef, Component, usize, usize, Option<Var>)> = m
            .errors
            .iter()
            .flat_map(|e| {
                e.terms.iter().map(move |t| {
                    (
                        e.frame,
                        e.component,
                        t.first,
                        t.coefficients,
                        t.factors.first().map(|f| f.var),
                    )
                })
            })
            .collect();
        use Component::*;
        use FrameRef::*;
        let (ax, dir) = (Var::Axis, Var::Direction);
        let expected = vec![
            (Workpiece(0), Ty, 0, 6, Some(ax(0))),
            (Workpiece(0), Ty, 6, 2, Some(ax(0))),
            (Workpiece(0), Ty, 8, 1, Some(dir(0))),
            (Workpiece(0), Ty, 9, 0, None),
            (Workpiece(0), Tx, 9, 4, Some(ax(0))),
            (Workpiece(0), Tz, 13, 4, Some(ax(0))),
            (Workpiece(0), Rx, 17, 5, Some(ax(0))),
            (Workpiece(0), Rx, 22, 4, Some(ax(1))),
            (Workpiece(0), Ry, 26, 5, Some(ax(0))),
            (Workpiece(0), Rz, 31, 5, Some(ax(0))),
            (Workpiece(1), Tx, 36, 7, Some(ax(1))),
            (Workpiece(1), Tx, 43, 2, Some(ax(1))),
            (Workpiece(1), Tx, 45, 1, Some(dir(1))),
            (Workpiece(1), Ty, 46, 5, Some(ax(1))),
            (Workpiece(1), Tz, 51, 5, Some(ax(1))),
            (Workpiece(1), Rx, 56, 5, Some(ax(1))),
            (Workpiece(1), Ry, 61, 5, Some(ax(1))),
            (Workpiece(1), Rz, 66, 5, Some(ax(1))),
            (Workpiece(1), Rz, 71, 1, None),
            (Tool(0), Tz, 72, 7, Some(ax(2))),
            (Tool(0), Tx, 79, 4, Some(ax(2))),
            (Tool(0), Ty, 83, 4, Some(ax(2))),
            (Tool(0), Rx, 87, 4, Some(ax(2))),
            (Tool(0), Rx, 91, 1, None),
            (Tool(0), Ry, 92, 4, Some(ax(2))),
            (Tool(0), Ry, 96, 1, None),
            (Tool(0), Rz, 97, 4, Some(ax(2))),
            (Workpiece(2), Tx, 101, 3, Some(ax(3))),
            (Workpiece(2), Ty, 104, 1, None),
            (Workpiece(2), Ty, 105, 4, Some(ax(3))),
            (Workpiece(2), Tz, 109, 1, None),
            (Workpiece(2), Tz, 110, 4, Some(ax(3))),
            (Workpiece(2), Ry, 114, 1, None),
            (Workpiece(2), Ry, 115, 1, Some(ax(3))),
            (Workpiece(2), Rz, 116, 1, None),
            (Workpiece(2), Rz, 117, 1, Some(ax(3))),
            (Workpiece(2), Rx, 118, 5, Some(ax(3))),
            (Workpiece(2), Rx, 123, 1, Some(dir(3))),
            (Workpiece(3), Tx, 124, 1, None),
            (Workpiece(3), Tx, 125, 6, Some(ax(4))),
            (Workpiece(3), Ty, 131, 1, None),
            (Workpiece(3), Ty, 132, 8, Some(ax(4))),
            (Workpiece(3), Tz, 140, 6, Some(ax(4))),
            (Workpiece(3), Rx, 146, 1, None),
            (Workpiece(3), Rx, 147, 4, Some(ax(4))),
            (Workpiece(3), Ry, 151, 1, None),
            (Workpiece(3), Ry, 152, 4, Some(ax(4))),
            (Workpiece(3), Rz, 156, 8, Some(ax(4))),
            (Workpiece(3), Rz, 164, 4, Some(ax(4))),
            (ToolEnd(None), Tz, 168, 1, None),
            (ToolEnd(None), Ry, 169, 1, None),
            (ToolEnd(Some(1)), Tx, 170, 1, None),
            (ToolEnd(Some(1)), Ty, 171, 1, None),
            (ToolEnd(Some(1)), Tz, 172, 1, None),
        ];
        ensure!(
            layout == expected,
            "the error models changed (update the baseline)"
        );
        let term = |frame: FrameRef, c: Component, i: usize| {
            m.errors
                .iter()
                .find(|e| e.frame == frame && e.component == c)
                .and_then(|e| e.terms.get(i))
                .ok_or_else(|| NotTheExample(format!("no term {i} of {frame:?}.{c:?}")))
        };
        let basis = |frame: FrameRef, c: Component, i: usize| {
            term(frame, c, i)?
                .factors
                .first()
                .map(|f| &f.basis)
                .ok_or_else(|| NotTheExample(format!("term {i} of {frame:?}.{c:?} has no factor")))
        };
        let harmonics = |c: Component, i: usize, h: &[u32]| -> Result<(), NotTheExample> {
            let b = basis(Workpiece(3), c, i)?;
            ensure!(
                b == &Basis::Fourier {
                    harmonics: h.to_vec(),
                    wavelength: None,
                },
                "C.{c:?} term {i} is {b:?}"
            );
            Ok(())
        };
        harmonics(Tx, 1, &[2, 3, 4])?;
        harmonics(Tz, 0, &[1, 2, 3])?;
        harmonics(Rx, 1, &[2, 3])?;
        harmonics(Ry, 1, &[2, 3])?;
        harmonics(Rz, 0, &[1, 2, 3, 4])?;
        harmonics(Rz, 1, &[90, 180])?;
        for (c, i) in [(Ty, 2), (Tx, 2)] {
            let f = if c == Ty { 0 } else { 1 };
            ensure!(
                matches!(basis(Workpiece(f), c, i)?, Basis::Sign),
                "no backlash term"
            );
        }
        let Basis::Spline {
            lo,
            hi,
            degree: 3,
            smooth: 2,
            detrend: Detrend::None,
            functions,
            ..
        } = basis(Tool(0), Tz, 0)?
        else {
            return Err(NotTheExample("Z.tz is not a cubic spline".into()));
        };
        let powers: Vec<(bool, u32)> = functions
            .iter()
            .map(|f| (f.g.knot.is_some(), f.g.power))
            .collect();
        ensure!(
            powers
                == [
                    (false, 1),
                    (false, 2),
                    (false, 3),
                    (true, 3),
                    (true, 3),
                    (true, 3),
                    (true, 3)
                ],
            "Z.tz has another layout"
        );
        let z_tz = (
            *lo,
            hi - lo,
            knots_of(&functions.iter().map(|f| f.g).collect::<Vec<_>>())?,
        );
        let Basis::Legendre {
            lo: a_lo,
            hi: a_hi,
            degree: 3,
        } = *basis(Workpiece(2), Tx, 0)?
        else {
            return Err(NotTheExample("A.tx is not a cubic polynomial".into()));
        };
        ensure!(
            basis(Workpiece(2), Ry, 1)? == &Basis::Linear { lo: a_lo, hi: a_hi },
            "A.ry is not linear"
        );
        let Basis::Spline {
            lo: c_lo, hi: c_hi, ..
        } = basis(Workpiece(3), Ty, 1)?
        else {
            return Err(NotTheExample("C.ty is not a spline".into()));
        };
        let c_mid = c_lo + 0.5 * (c_hi - c_lo);
        // Lags read in the tool terms.
        ensure!(
            term(ToolEnd(None), Tz, 0)?.scale == Scalar::Var(Var::Lag(0)),
            "tool.tz is not scaled by the first lag"
        );
        ensure!(
            term(ToolEnd(None), Ry, 0)?.scale == Scalar::Var(Var::Lag(1)),
            "tool.ry is not scaled by the second lag"
        );
        // Every scale is evaluated by `scalar`, which reads the state without checks.
        ensure!(
            m.inputs.len() == 3 && m.lags.len() == 2,
            "{} inputs and {} lags",
            m.inputs.len(),
            m.lags.len()
        );
        let shape = |chain: &[kin_compiler::ir::Element], k: usize| {
            chain
                .get(k)
                .map(|e| e.shape.translation)
                .unwrap_or_default()
        };
        Ok(Baseline {
            trig,
            s_y: shape(&m.workpiece_chain, 0),
            s_x: shape(&m.workpiece_chain, 1),
            s_a: shape(&m.workpiece_chain, 2),
            s_c: shape(&m.workpiece_chain, 3),
            s_z: shape(&m.tool_chain, 0),
            tools: m.tools.iter().map(|t| t.offset.translation).collect(),
            y_ty: quad(basis(Workpiece(0), Ty, 0)?, Detrend::None)?,
            y_per: periodic2(basis(Workpiece(0), Ty, 1)?)?,
            y_str: quad(basis(Workpiece(0), Tx, 0)?, Detrend::Line)?,
            y_rot: quad(basis(Workpiece(0), Rx, 0)?, Detrend::None)?,
            x_load: quad(basis(Workpiece(0), Rx, 1)?, Detrend::None)?,
            x_tx: quad(basis(Workpiece(1), Tx, 0)?, Detrend::None)?,
            x_per: periodic2(basis(Workpiece(1), Tx, 1)?)?,
            x_str: quad(basis(Workpiece(1), Ty, 0)?, Detrend::Line)?,
            x_rot: quad(basis(Workpiece(1), Rx, 0)?, Detrend::None)?,
            z_tz,
            z_str: quad(basis(Tool(0), Tx, 0)?, Detrend::Line)?,
            z_rot: quad(basis(Tool(0), Rx, 0)?, Detrend::None)?,
            a_lo,
            a_span: a_hi - a_lo,
            a_sp2: quad(basis(Workpiece(2), Ty, 1)?, Detrend::None)?,
            a_sp3: quad(basis(Workpiece(2), Rx, 0)?, Detrend::None)?,
            c_rev: quad(basis(Workpiece(3), Ty, 1)?, Detrend::OncePerRev)?,
            c_mid,
            y_scale: term(Workpiece(0), Ty, 3)?.scale.clone(),
            y_load: term(Workpiece(0), Rx, 1)?.scale.clone(),
        })
    }

    /// What this evaluator read from the machine — chain offsets, tool offsets, every spline's
    /// range, knots and trends, the periodic terms' α, the two scalings' expressions — as JSON,
    /// so that a model of the same machine written with another tool (the CasADi comparison of
    /// `runtime/bench/casadi/`) takes the same numbers rather than working them out again.
    pub fn tables(&self) -> serde_json::Value {
        use serde_json::json;
        fn quad<const M: usize>(q: &Quad<M>) -> serde_json::Value {
            json!({ "lo": q.lo, "span": q.span, "knots": &q.knots[..], "trend": &q.trend[..] })
        }
        let periodic =
            |p: &Periodic2| json!({ "tau": p.tau, "knots": &p.knots[..], "alpha": &p.alpha[..] });
        json!({
            "coefficients": N,
            "s_y": self.s_y, "s_x": self.s_x, "s_a": self.s_a, "s_c": self.s_c, "s_z": self.s_z,
            "tools": self.tools,
            "y_ty": quad(&self.y_ty), "y_per": periodic(&self.y_per),
            "y_str": quad(&self.y_str), "y_rot": quad(&self.y_rot), "x_load": quad(&self.x_load),
            "x_tx": quad(&self.x_tx), "x_per": periodic(&self.x_per),
            "x_str": quad(&self.x_str), "x_rot": quad(&self.x_rot),
            "z_tz": { "lo": self.z_tz.0, "span": self.z_tz.1, "knots": self.z_tz.2 },
            "z_str": quad(&self.z_str), "z_rot": quad(&self.z_rot),
            "a_lo": self.a_lo, "a_span": self.a_span,
            "a_sp2": quad(&self.a_sp2), "a_sp3": quad(&self.a_sp3),
            "c_rev": quad(&self.c_rev), "c_mid": self.c_mid,
            "y_scale": self.y_scale, "y_load": self.y_load,
        })
    }

    /// The error (position task: actual − nominal) and its β-Jacobian, 6 × n row-major.
    ///
    /// # Panics
    ///
    /// When the state, `beta` or `jac` do not have the example's sizes, or the tool index is out
    /// of range: a yardstick reads its buffers without the checks an engine makes (callers size
    /// them from the machine, as [`crate`] does).
    pub fn error_and_jacobian(
        &mut self,
        st: &State,
        beta: &[f64],
        _nonlinear: &[f64],
        err: &mut [f64; 6],
        jac: &mut [f64],
    ) {
        self.eval::<6, true>(st, beta, err, jac);
    }

    /// The position rows only: the error's three position components and the 3 × n
    /// Jacobian of a position-only data set (what [`kin_model::jit::Observed::POSITION`] asks
    /// the JIT for). Panics as [`Baseline::error_and_jacobian`].
    pub fn position_error_and_jacobian(
        &mut self,
        st: &State,
        beta: &[f64],
        err: &mut [f64; 3],
        jac: &mut [f64],
    ) {
        self.eval::<3, true>(st, beta, err, jac);
    }

    /// The six error components alone (what a compensation needs), no Jacobian.
    pub fn error(&mut self, st: &State, beta: &[f64]) -> [f64; 6] {
        let mut err = [0.0; 6];
        self.eval::<6, false>(st, beta, &mut err, &mut []);
        err
    }

    /// The first `R` error components and, with `JAC`, the first `R` rows of the Jacobian
    /// (`R × n` row-major in `jac`): one body for the three ways the benchmark calls it, the
    /// unused rows and stores removed by the compiler.
    #[inline(always)]
    fn eval<const R: usize, const JAC: bool>(
        &mut self,
        st: &State,
        beta: &[f64],
        err: &mut [f64; R],
        jac: &mut [f64],
    ) {
        // A fixed length, so that the constant offsets below need no bounds check.
        let jac = &mut jac[..if JAC { R * N } else { 0 }];
        let beta: &[f64; N] = beta.try_into().expect("173 coefficients");
        let [y, x, z, a, c] = [st.q[0], st.q[1], st.q[2], st.q[3], st.q[4]];

        // ---- Kinematics (fixed frames sit before their joints, eq. 2.35–2.38).
        let (sa, ca) = libm::sincos(a);
        let (sc, cc) = libm::sincos(c);
        let p_y = self.s_y;
        let p_x = [
            p_y[0] + self.s_x[0],
            p_y[1] - y + self.s_x[1],
            p_y[2] + self.s_x[2],
        ];
        let p_a = [
            p_x[0] - x + self.s_a[0],
            p_x[1] + self.s_a[1],
            p_x[2] + self.s_a[2],
        ];
        let s_c = self.s_c;
        // C sits at p_A + R_x(a)·s_C; wr is C's frame turned by c (S_wr = I).
        let p_c = [
            p_a[0] + s_c[0],
            p_a[1] + (ca * s_c[1] - sa * s_c[2]),
            p_a[2] + (sa * s_c[1] + ca * s_c[2]),
        ];
        // M = R(wr→base)ᵀ = (R_x(a)·R_z(c))ᵀ, by rows.
        let m = [
            [cc, ca * sc, sa * sc],
            [-sc, ca * cc, sa * cc],
            [0.0, -sa, ca],
        ];
        let t = st.tool_offset.unwrap_or(self.tools[st.tool]);
        let p_z = [self.s_z[0], self.s_z[1], self.s_z[2] + z];
        let p_t = [p_z[0] + t[0], p_z[1] + t[1], p_z[2] + t[2]];
        let arm = |p: [f64; 3]| {
            let d = [p_t[0] - p[0], p_t[1] - p[1], p_t[2] - p[2]];
            [0, 1, 2].map(|i| m[i][0] * d[0] + m[i][1] * d[1] + m[i][2] * d[2])
        };
        // Columns of F = sign·[[R, −[a]×R], [0, R]] with R the frame's rotation in wr axes.
        let tcol = |r: [f64; 3]| r;
        let rcol = |r: [f64; 3], a: [f64; 3]| {
            [
                r[1] * a[2] - r[2] * a[1],
                r[2] * a[0] - r[0] * a[2],
                r[0] * a[1] - r[1] * a[0],
                r[0],
                r[1],
                r[2],
            ]
        };
        let mc = [
            [m[0][0], m[1][0], m[2][0]],
            [m[0][1], m[1][1], m[2][1]],
            [m[0][2], m[1][2], m[2][2]],
        ];
        let neg = |v: [f64; 3]| [-v[0], -v[1], -v[2]];
        let nm = [neg(mc[0]), neg(mc[1]), neg(mc[2])];
        // C: −R_z(c)ᵀ.
        let nrc = [[-cc, sc, 0.0], [-sc, -cc, 0.0], [0.0, 0.0, -1.0]];

        // ---- Trigonometry of C's basis factors (continuous axis: one turn).
        let xc = c.rem_euclid(std::f64::consts::TAU);
        let (h1, h2, h3, h4, h90, h180, rev) = match self.trig {
            Trig::Exact => {
                let f = |h: f64| libm::sincos(h * xc);
                (
                    f(1.0),
                    f(2.0),
                    f(3.0),
                    f(4.0),
                    f(90.0),
                    f(180.0),
                    libm::sincos(xc - self.c_mid),
                )
            }
            Trig::Recurrence => {
                let h1 = if xc == c { (sc, cc) } else { libm::sincos(xc) };
                let h2 = add_angles(h1, h1);
                let h3 = add_angles(h2, h1);
                let h4 = add_angles(h2, h2);
                let h90 = libm::sincos(90.0 * xc);
                // The midpoint of a full turn is π: sin(x − π) = −sin x.
                (h1, h2, h3, h4, h90, add_angles(h90, h90), (-h1.0, -h1.1))
            }
        };
        let cs = |h: (f64, f64)| [h.1, h.0];

        let mut e = [0.0; 6];
        let acc_t = |e: &mut [f64; 6], col: &[f64; 3], v: f64| {
            for r in 0..3 {
                e[r] += col[r] * v;
            }
        };
        let acc_r = |e: &mut [f64; 6], col: &[f64; 6], v: f64| {
            for r in 0..6 {
                e[r] += col[r] * v;
            }
        };

        // ---- Y (workpiece chain: −M).
        {
            let (ay, cty, ctx, ctz) = (arm(p_y), tcol(nm[1]), tcol(nm[0]), tcol(nm[2]));
            let v: [f64; 9] = cat::<8, 1, 9>(
                cat::<6, 2, 8>(self.y_ty.plain(y), self.y_per.values(y)),
                [st.dirs[0]],
            );
            let fixed = scalar(&self.y_scale, st);
            let value = put_t(jac, R, JAC, beta, 0, &cty, &v) + fixed;
            acc_t(&mut e, &cty, value);
            let s: [f64; 4] = self.y_str.straight(y);
            let value = put_t(jac, R, JAC, beta, 9, &ctx, &s);
            acc_t(&mut e, &ctx, value);
            let value = put_t(jac, R, JAC, beta, 13, &ctz, &s);
            acc_t(&mut e, &ctz, value);
            let r: [f64; 5] = self.y_rot.plain(y);
            let load = scalar(&self.y_load, st);
            let xl: [f64; 4] = self.x_load.plain(x);
            let v: [f64; 9] = cat::<5, 4, 9>(r, xl.map(|v| load * v));
            let col = rcol(nm[0], ay);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 17, &col, &v));
            let col = rcol(nm[1], ay);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 26, &col, &r));
            let col = rcol(nm[2], ay);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 31, &col, &r));
        }
        // ---- X (−M).
        {
            let ax = arm(p_x);
            let v: [f64; 10] = cat::<9, 1, 10>(
                cat::<7, 2, 9>(self.x_tx.plain(x), self.x_per.values(x)),
                [st.dirs[1]],
            );
            acc_t(&mut e, &nm[0], put_t(jac, R, JAC, beta, 36, &nm[0], &v));
            let s: [f64; 5] = self.x_str.straight(x);
            acc_t(&mut e, &nm[1], put_t(jac, R, JAC, beta, 46, &nm[1], &s));
            acc_t(&mut e, &nm[2], put_t(jac, R, JAC, beta, 51, &nm[2], &s));
            let r: [f64; 5] = self.x_rot.plain(x);
            let col = rcol(nm[0], ax);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 56, &col, &r));
            let col = rcol(nm[1], ax);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 61, &col, &r));
            let col = rcol(nm[2], ax);
            acc_r(
                &mut e,
                &col,
                put_r(jac, R, JAC, beta, 66, &col, &cat::<5, 1, 6>(r, [1.0])),
            );
        }
        // ---- Z (tool chain: +M).
        {
            let az = arm(p_z);
            let (lo, span, knots) = self.z_tz;
            let s = (z - lo) / span;
            let s2 = s * s;
            let cube = |d: f64| d * d * d;
            let mut v = [s, s2, s2 * s, 0.0, 0.0, 0.0, 0.0];
            for k in 0..4 {
                v[3 + k] = cube((s - knots[k]).max(0.0));
            }
            acc_t(&mut e, &mc[2], put_t(jac, R, JAC, beta, 72, &mc[2], &v));
            let st4: [f64; 4] = self.z_str.straight(z);
            acc_t(&mut e, &mc[0], put_t(jac, R, JAC, beta, 79, &mc[0], &st4));
            acc_t(&mut e, &mc[1], put_t(jac, R, JAC, beta, 83, &mc[1], &st4));
            let r: [f64; 4] = self.z_rot.plain(z);
            let r1: [f64; 5] = cat::<4, 1, 5>(r, [1.0]);
            let col = rcol(mc[0], az);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 87, &col, &r1));
            let col = rcol(mc[1], az);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 92, &col, &r1));
            let col = rcol(mc[2], az);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 97, &col, &r));
        }
        // ---- A (−M).
        {
            let aa = arm(p_a);
            let u = 2.0 * ((a - self.a_lo) / self.a_span) - 1.0;
            let p2 = (3.0 * u * u - 1.0) / 2.0;
            let p3 = (5.0 * u * p2 - 2.0 * u) / 3.0;
            acc_t(
                &mut e,
                &nm[0],
                put_t(jac, R, JAC, beta, 101, &nm[0], &[u, p2, p3]),
            );
            let sp: [f64; 4] = self.a_sp2.plain(a);
            let v: [f64; 5] = cat::<1, 4, 5>([1.0], sp);
            acc_t(&mut e, &nm[1], put_t(jac, R, JAC, beta, 104, &nm[1], &v));
            acc_t(&mut e, &nm[2], put_t(jac, R, JAC, beta, 109, &nm[2], &v));
            let col = rcol(nm[1], aa);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 114, &col, &[1.0, u]));
            let col = rcol(nm[2], aa);
            acc_r(&mut e, &col, put_r(jac, R, JAC, beta, 116, &col, &[1.0, u]));
            let r: [f64; 5] = self.a_sp3.plain(a);
            let col = rcol(nm[0], aa);
            acc_r(
                &mut e,
                &col,
                put_r(
                    jac,
                    R,
                    JAC,
                    beta,
                    118,
                    &col,
                    &cat::<5, 1, 6>(r, [st.dirs[3]]),
                ),
            );
        }
        // ---- C (−R_z(c)ᵀ).
        {
            let ac = arm(p_c);
            let [c1, s1] = cs(h1);
            let [c2, s2] = cs(h2);
            let [c3, s3] = cs(h3);
            let [c4, s4] = cs(h4);
            let [c90, s90] = cs(h90);
            let [c180, s180] = cs(h180);
            acc_t(
                &mut e,
                &nrc[0],
                put_t(
                    jac,
                    R,
                    JAC,
                    beta,
                    124,
                    &nrc[0],
                    &[1.0, c2, s2, c3, s3, c4, s4],
                ),
            );
            let g: [f64; 8] = self.c_rev.no_rev(xc, rev.1, rev.0);
            acc_t(
                &mut e,
                &nrc[1],
                put_t(jac, R, JAC, beta, 131, &nrc[1], &cat::<1, 8, 9>([1.0], g)),
            );
            acc_t(
                &mut e,
                &nrc[2],
                put_t(jac, R, JAC, beta, 140, &nrc[2], &[c1, s1, c2, s2, c3, s3]),
            );
            let col = rcol(nrc[0], ac);
            acc_r(
                &mut e,
                &col,
                put_r(jac, R, JAC, beta, 146, &col, &[1.0, c2, s2, c3, s3]),
            );
            let col = rcol(nrc[1], ac);
            acc_r(
                &mut e,
                &col,
                put_r(jac, R, JAC, beta, 151, &col, &[1.0, c2, s2, c3, s3]),
            );
            let col = rcol(nrc[2], ac);
            acc_r(
                &mut e,
                &col,
                put_r(
                    jac,
                    R,
                    JAC,
                    beta,
                    156,
                    &col,
                    &[c1, s1, c2, s2, c3, s3, c4, s4, c90, s90, c180, s180],
                ),
            );
        }
        // ---- Tools (+M, no arm): thermal growth of every tool, offsets of the probe.
        {
            let col = mc[2];
            acc_t(
                &mut e,
                &col,
                put_t(jac, R, JAC, beta, 168, &col, &[st.lags[0]]),
            );
            let col = rcol(mc[1], [0.0; 3]);
            acc_r(
                &mut e,
                &col,
                put_r(jac, R, JAC, beta, 169, &col, &[st.lags[1]]),
            );
            let probe = st.tool == 1;
            let z3 = [0.0; 3];
            for (k, colp) in mc.iter().enumerate() {
                let col = if probe { colp } else { &z3 };
                acc_t(&mut e, col, put_t(jac, R, JAC, beta, 170 + k, col, &[1.0]));
            }
        }
        err.copy_from_slice(&e[..R]);
    }
}
