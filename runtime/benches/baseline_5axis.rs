//! A hand-written, hand-optimised evaluator of `examples/milling_5axis.kin`: the yardstick the
//! JIT is measured against (issue 4). It computes the same error and full 6 × n β-Jacobian as
//! the interpreter (the tests check agreement to 1e-12), written as one would write it in C for
//! this one machine:
//!
//! * the kinematics in closed form: the workpiece chain Y, X, A, C has only fixed frames and
//!   axis-aligned joints, the tool chain one moving Z, so `R(wr→base) = R_z(−c)·R_x(−a)` and
//!   every frame's origin is a few additions; the F-matrices of Y, X, A, Z and the tool share
//!   that one rotation;
//! * the basis values evaluated once per distinct factor (the three `spline(Y, knots 3)` of
//!   Y.rx/ry/rz are one), from tables of knots, trends and α's taken from the compiled model;
//! * the Jacobian written column block by column block through pre-split row slices, with the
//!   structural zeros of translation components written as zeros (the buffer is reused, every
//!   entry is written, as the JIT does).
//!
//! It uses `libm::sincos` for every angle the interpreter takes a sine of, so that the numbers
//! are the interpreter's; harmonic recurrences would save calls but not compute the same numbers.

use kin_compiler::basis::{Basis, Detrend, Power, Wavelength};
use kin_compiler::ir::{Component, FrameKind, FrameRef, JointKind, Machine, Scalar, Var};
use kin_runtime::interp::State;

/// Which F-matrix a component uses.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Frame {
    Y,
    X,
    A,
    C,
    Z,
    /// `tool.*`: every tool's frame.
    Tool,
    /// `probe.*` (or another single tool): only when that tool is selected.
    OneTool(usize),
}

#[derive(Clone, Debug)]
enum Family {
    Const,
    Sign,
    Linear { lo: f64, span: f64 },
    Legendre { lo: f64, span: f64, degree: u32 },
    Spline { lo: f64, span: f64, mid: f64, detrend: Detrend, functions: Vec<(Power, [f64; 2])> },
    Fourier { harmonics: Vec<f64> },
    Periodic { tau: Option<f64>, tau_index: usize, phase: f64, functions: Vec<(Power, Vec<f64>)> },
}

#[derive(Clone, Debug)]
struct Factor {
    var: Var,
    continuous: bool,
    family: Family,
    /// Where its values go in the per-pose value table.
    offset: usize,
}

#[derive(Clone, Debug)]
struct Term {
    /// `None`: the scale is 1.
    scale: Option<Scalar>,
    factor: Option<usize>,
    first: usize,
    count: usize,
}

#[derive(Clone, Debug)]
struct Comp {
    frame: Frame,
    component: Component,
    terms: Vec<Term>,
}

pub struct Baseline {
    n: usize,
    axes: [usize; 5],
    /// Base-frame origins of the fixed frames at zero joint positions, and the constant parts
    /// of the chains (shape translations), read from the model.
    s_y: [f64; 3],
    s_x: [f64; 3],
    s_a: [f64; 3],
    s_c: [f64; 3],
    s_z: [f64; 3],
    tools: Vec<[f64; 3]>,
    factors: Vec<Factor>,
    comps: Vec<Comp>,
    values: Vec<f64>,
}

fn ipow(u: f64, n: u32) -> f64 {
    match n {
        0 => 1.0,
        1 => u,
        2 => u * u,
        3 => u * u * u,
        _ => {
            let mut r = u;
            for _ in 1..n {
                r *= u;
            }
            r
        }
    }
}

fn power(p: Power, u: f64) -> f64 {
    match p.knot {
        None => ipow(u, p.power),
        Some(t) => {
            if u > t {
                ipow(u - t, p.power)
            } else {
                0.0
            }
        }
    }
}

fn scalar(s: &Scalar, st: &State) -> f64 {
    match s {
        Scalar::Num(x) => *x,
        Scalar::Var(v) => var(*v, st),
        Scalar::Neg(a) => -scalar(a, st),
        Scalar::Add(a, b) => scalar(a, st) + scalar(b, st),
        Scalar::Sub(a, b) => scalar(a, st) - scalar(b, st),
        Scalar::Mul(a, b) => scalar(a, st) * scalar(b, st),
        Scalar::Div(a, b) => scalar(a, st) / scalar(b, st),
        Scalar::Sin(a) => libm::sin(scalar(a, st)),
        Scalar::Cos(a) => libm::cos(scalar(a, st)),
    }
}

fn var(v: Var, st: &State) -> f64 {
    match v {
        Var::Axis(i) => st.q[i],
        Var::Input(i) => st.inputs[i],
        Var::Lag(i) => st.lags[i],
        Var::Time => st.time,
        Var::Direction(i) => st.dirs[i],
    }
}

impl Baseline {
    /// Reads the tables of `m`, which must be the 5-axis example (panics otherwise: this is a
    /// baseline for one machine, not an engine).
    pub fn new(m: &Machine) -> Baseline {
        let axis = |name: &str| m.axes.iter().position(|a| a.name == name).expect("axis");
        let axes = [axis("Y"), axis("X"), axis("Z"), axis("A"), axis("C")];
        let wp: Vec<usize> = m.workpiece_chain.iter().map(|e| e.axis).collect();
        assert_eq!(wp, vec![axes[0], axes[1], axes[3], axes[4]], "workpiece chain Y X A C");
        assert!(m.workpiece_chain.iter().all(|e| e.frame == FrameKind::Fixed && e.shape.rotation == [0.0; 3]));
        assert_eq!(m.tool_chain.len(), 1);
        assert_eq!(m.tool_chain[0].frame, FrameKind::Moving);
        assert!(m.tools.iter().all(|t| t.offset.rotation == [0.0; 3]));
        assert_eq!(m.workpiece.translation, [0.0; 3]);
        assert_eq!(m.workpiece.rotation, [0.0; 3]);
        let dirs: Vec<([f64; 3], JointKind)> = axes.iter().map(|&a| (m.axes[a].direction, m.axes[a].kind)).collect();
        assert_eq!(dirs[0], ([0.0, -1.0, 0.0], JointKind::Prismatic));
        assert_eq!(dirs[1], ([-1.0, 0.0, 0.0], JointKind::Prismatic));
        assert_eq!(dirs[2], ([0.0, 0.0, 1.0], JointKind::Prismatic));
        assert_eq!(dirs[3], ([1.0, 0.0, 0.0], JointKind::Revolute));
        assert_eq!(dirs[4], ([0.0, 0.0, 1.0], JointKind::Revolute));

        let mut factors: Vec<Factor> = Vec::new();
        let mut keys: Vec<(Var, String)> = Vec::new();
        let mut size = 0;
        let mut comps = Vec::new();
        for e in &m.errors {
            let frame = match e.frame {
                FrameRef::Workpiece(0) => Frame::Y,
                FrameRef::Workpiece(1) => Frame::X,
                FrameRef::Workpiece(2) => Frame::A,
                FrameRef::Workpiece(3) => Frame::C,
                FrameRef::Tool(0) => Frame::Z,
                FrameRef::ToolEnd(None) => Frame::Tool,
                FrameRef::ToolEnd(Some(i)) => Frame::OneTool(i),
                f => panic!("unexpected frame {f:?}"),
            };
            let mut terms = Vec::new();
            for t in &e.terms {
                assert!(t.factors.len() <= 1, "single-factor terms only");
                let factor = t.factors.first().map(|f| {
                    let key = (f.var, format!("{:?}", f.basis));
                    if let Some(k) = keys.iter().position(|k| *k == key) {
                        return k;
                    }
                    let family = match &f.basis {
                        Basis::Const => Family::Const,
                        Basis::Sign => Family::Sign,
                        Basis::Linear { lo, hi } => Family::Linear { lo: *lo, span: hi - lo },
                        Basis::Legendre { lo, hi, degree } => Family::Legendre { lo: *lo, span: hi - lo, degree: *degree },
                        Basis::Spline { lo, hi, detrend, functions, .. } => Family::Spline {
                            lo: *lo,
                            span: hi - lo,
                            mid: lo + 0.5 * (hi - lo),
                            detrend: *detrend,
                            functions: functions.iter().map(|f| (f.g, f.trend)).collect(),
                        },
                        Basis::Fourier { harmonics } => Family::Fourier { harmonics: harmonics.iter().map(|h| f64::from(*h)).collect() },
                        Basis::Periodic { wavelength, phase, functions, .. } => {
                            let (tau, tau_index) = match wavelength {
                                Wavelength::Fixed(t) => (Some(*t), 0),
                                Wavelength::Fitted(p) => (None, p.index),
                            };
                            Family::Periodic { tau, tau_index, phase: *phase, functions: functions.iter().map(|f| (f.g, f.alpha.clone())).collect() }
                        }
                    };
                    let continuous = matches!(f.var, Var::Axis(a) if m.axes[a].continuous);
                    factors.push(Factor { var: f.var, continuous, family, offset: size });
                    size += f.basis.size();
                    keys.push(key);
                    factors.len() - 1
                });
                let scale = match t.scale {
                    Scalar::Num(v) if v == 1.0 => None,
                    ref s => Some(s.clone()),
                };
                terms.push(Term { scale, factor, first: t.first, count: t.coefficients });
            }
            comps.push(Comp { frame, component: e.component, terms });
        }
        Baseline {
            n: m.coefficients.len(),
            axes,
            s_y: m.workpiece_chain[0].shape.translation,
            s_x: m.workpiece_chain[1].shape.translation,
            s_a: m.workpiece_chain[2].shape.translation,
            s_c: m.workpiece_chain[3].shape.translation,
            s_z: m.tool_chain[0].shape.translation,
            tools: m.tools.iter().map(|t| t.offset.translation).collect(),
            factors,
            comps,
            values: vec![0.0; size],
        }
    }

    /// Basis values of every distinct factor at this state.
    fn factors(&mut self, st: &State, nonlinear: &[f64]) {
        let values = &mut self.values;
        for f in &self.factors {
            let mut x = var(f.var, st);
            if f.continuous {
                x = x.rem_euclid(std::f64::consts::TAU);
            }
            let out = &mut values[f.offset..];
            match &f.family {
                Family::Const => out[0] = 1.0,
                Family::Sign => out[0] = x,
                Family::Linear { lo, span } => out[0] = 2.0 * ((x - lo) / span) - 1.0,
                Family::Legendre { lo, span, degree } => {
                    let u = 2.0 * ((x - lo) / span) - 1.0;
                    let (mut prev, mut cur) = (1.0, u);
                    for k in 0..*degree as usize {
                        out[k] = cur;
                        let n = (k + 1) as f64;
                        let next = ((2.0 * n + 1.0) * u * cur - n * prev) / (n + 1.0);
                        prev = cur;
                        cur = next;
                    }
                }
                Family::Spline { lo, span, mid, detrend, functions } => {
                    let s = (x - lo) / span;
                    match detrend {
                        Detrend::None => {
                            for (o, (g, _)) in out.iter_mut().zip(functions) {
                                *o = power(*g, s);
                            }
                        }
                        Detrend::Line => {
                            for (o, (g, t)) in out.iter_mut().zip(functions) {
                                *o = power(*g, s) - (t[0] + t[1] * s);
                            }
                        }
                        Detrend::OncePerRev => {
                            let (sn, c) = libm::sincos(x - mid);
                            for (o, (g, t)) in out.iter_mut().zip(functions) {
                                *o = power(*g, s) - t[0] * c - t[1] * sn;
                            }
                        }
                    }
                }
                Family::Fourier { harmonics } => {
                    for (pair, h) in out.chunks_exact_mut(2).zip(harmonics) {
                        let (s, c) = libm::sincos(h * x);
                        pair[0] = c;
                        pair[1] = s;
                    }
                }
                Family::Periodic { tau, tau_index, phase, functions } => {
                    let tau = tau.unwrap_or_else(|| nonlinear[*tau_index]);
                    let y = (x - phase) / tau;
                    let mut w = y - y.floor();
                    if w >= 1.0 {
                        w = 0.0;
                    }
                    for (o, (g, alpha)) in out.iter_mut().zip(functions) {
                        let mut acc = 0.0;
                        for a in alpha.iter().rev() {
                            acc = acc * w + a;
                        }
                        *o = power(*g, w) - acc * w;
                    }
                }
            }
        }
    }

    /// The error (position task: actual − nominal) and its β-Jacobian, 6 × n row-major.
    pub fn error_and_jacobian(&mut self, st: &State, beta: &[f64], nonlinear: &[f64], err: &mut [f64; 6], jac: &mut [f64]) {
        let n = self.n;
        assert_eq!(jac.len(), 6 * n);
        assert_eq!(beta.len(), n);
        let [iy, ix, iz, ia, ic] = self.axes;
        let (y, x, z, a, c) = (st.q[iy], st.q[ix], st.q[iz], st.q[ia], st.q[ic]);
        self.factors(st, nonlinear);

        // Kinematics. Workpiece chain, all frames fixed (before their joints):
        //   Y at s_y; X at s_y + J_Y + s_x; A at … + J_X + s_a; C at p_A + R_x(a)·s_c.
        let (sa, ca) = libm::sincos(a);
        let (sc, cc) = libm::sincos(c);
        let p_y = self.s_y;
        let p_x = [p_y[0] + self.s_x[0], p_y[1] - y + self.s_x[1], p_y[2] + self.s_x[2]];
        let p_a = [p_x[0] - x + self.s_a[0], p_x[1] + self.s_a[1], p_x[2] + self.s_a[2]];
        let s_c = self.s_c;
        let p_c = [p_a[0] + s_c[0], p_a[1] + ca * s_c[1] - sa * s_c[2], p_a[2] + sa * s_c[1] + ca * s_c[2]];
        // wr = C's frame turned by c (S_wr = I): origin p_c, R_wr = R_x(a)·R_z(c).
        // M = R_wrᵀ, rows: the wr axes in base coordinates.
        let m = [[cc, ca * sc, sa * sc], [-sc, ca * cc, sa * cc], [0.0, -sa, ca]];
        // Tool chain: Z moving, then the tool offset.
        let t = st.tool_offset.unwrap_or(self.tools[st.tool]);
        let p_z = [self.s_z[0], self.s_z[1], self.s_z[2] + z];
        let p_t = [p_z[0] + t[0], p_z[1] + t[1], p_z[2] + t[2]];
        let mv = |v: [f64; 3]| {
            [
                m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
                m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
                m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
            ]
        };
        let arm = |p: [f64; 3]| mv([p_t[0] - p[0], p_t[1] - p[1], p_t[2] - p[2]]);
        let (a_y, a_x, a_a, a_c, a_z) = (arm(p_y), arm(p_x), arm(p_a), arm(p_c), arm(p_z));
        // Rotation blocks (sign included): workpiece frames −M (Y, X, A) and −R_z(c)ᵀ (C),
        // Z and the tool +M. Stored column-wise: r[j] is column j.
        let mcol = [[m[0][0], m[1][0], m[2][0]], [m[0][1], m[1][1], m[2][1]], [m[0][2], m[1][2], m[2][2]]];
        let neg = |v: [f64; 3]| [-v[0], -v[1], -v[2]];
        let neg_m = [neg(mcol[0]), neg(mcol[1]), neg(mcol[2])];
        let neg_rc = [[-cc, sc, -0.0], [-sc, -cc, -0.0], [-0.0, -0.0, -1.0]];
        let zero3 = [0.0; 3];

        let mut total = [0.0; 6];
        let (r0, rest) = jac.split_at_mut(n);
        let (r1, rest) = rest.split_at_mut(n);
        let (r2, rest) = rest.split_at_mut(n);
        let (r3, rest) = rest.split_at_mut(n);
        let (r4, r5) = rest.split_at_mut(n);
        for comp in &self.comps {
            let (rot, arm_v) = match comp.frame {
                Frame::Y => (&neg_m, a_y),
                Frame::X => (&neg_m, a_x),
                Frame::A => (&neg_m, a_a),
                Frame::C => (&neg_rc, a_c),
                Frame::Z => (&mcol, a_z),
                Frame::Tool | Frame::OneTool(_) => (&mcol, zero3),
            };
            let active = match comp.frame {
                Frame::OneTool(i) => i == st.tool,
                _ => true,
            };
            let j3 = comp.component.index() % 3;
            let rj = rot[j3];
            // Column of F = [[R, −[a]×R], [0, R]]: translation (R_j, 0), rotation (R_j × a, R_j).
            let col = if !active {
                [0.0; 6]
            } else if comp.component.is_rotation() {
                let ar = arm_v;
                [rj[1] * ar[2] - rj[2] * ar[1], rj[2] * ar[0] - rj[0] * ar[2], rj[0] * ar[1] - rj[1] * ar[0], rj[0], rj[1], rj[2]]
            } else {
                [rj[0], rj[1], rj[2], 0.0, 0.0, 0.0]
            };
            let mut value = 0.0;
            for term in &comp.terms {
                let scale = term.scale.as_ref().map_or(1.0, |s| scalar(s, st));
                if term.count == 0 {
                    // A known, fixed error.
                    if active {
                        value += scale;
                    }
                    continue;
                }
                // `const` is a term without factors and with one coefficient.
                let vals = match term.factor {
                    Some(fi) => {
                        let off = self.factors[fi].offset;
                        &self.values[off..off + term.count]
                    }
                    None => &[1.0][..],
                };
                let range = term.first..term.first + term.count;
                let b = &beta[range.clone()];
                let rows = (&mut r0[range.clone()], &mut r1[range.clone()], &mut r2[range.clone()]);
                let (o0, o1, o2) = rows;
                if comp.component.is_rotation() {
                    let (o3, o4, o5) = (&mut r3[range.clone()], &mut r4[range.clone()], &mut r5[range.clone()]);
                    for k in 0..term.count {
                        let v = scale * vals[k];
                        o0[k] = col[0] * v;
                        o1[k] = col[1] * v;
                        o2[k] = col[2] * v;
                        o3[k] = col[3] * v;
                        o4[k] = col[4] * v;
                        o5[k] = col[5] * v;
                        value += v * b[k];
                    }
                } else {
                    for k in 0..term.count {
                        let v = scale * vals[k];
                        o0[k] = col[0] * v;
                        o1[k] = col[1] * v;
                        o2[k] = col[2] * v;
                        value += v * b[k];
                    }
                    r3[range.clone()].fill(0.0);
                    r4[range.clone()].fill(0.0);
                    r5[range].fill(0.0);
                }
            }
            for r in 0..6 {
                total[r] += col[r] * value;
            }
        }
        *err = total;
    }
}
