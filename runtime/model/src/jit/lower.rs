//! The IR of one machine as expression graphs: one per generated function.
//!
//! The graphs compute exactly what the interpreter computes, specialised to the model:
//!
//! * **Kinematics** (`kinematics.rs`, eq. 2.35–2.38): every chain is the product
//!   `S_1 J_1 S_2 J_2 … S_n J_n S_end` from the base; the shape transforms are constants, so a
//!   product with an identity rotation or a zero translation folds away, and only the joints'
//!   `sin q`, `cos q` and the products that involve them remain.
//! * **F-matrix columns** (eq. 2.24–2.28 in wr axes, see the module docs of `kinematics.rs`):
//!   `F_k = sign·[[R, −[a]× R], [0, R]]`; only the columns of the components that carry an error
//!   model are built, so a frame with a `tx` model costs three products, not a 6×6 matrix.
//! * **Basis values** (`basis.rs`): the same operations in the same order as `Basis::eval`, with
//!   knots, trends and α's as immediates; values shared between components are built once.
//! * **Jacobian** (eq. 4.2, the design matrix): the model is linear in β and every β belongs to
//!   one component of one frame, so column `j` is `task_sign × F-column(frame, component) ×
//!   (scale × Π basis values)` — six products per coefficient and nothing else.

use std::f64::consts::TAU;

use kin_compiler::basis::{
    harmonic_step, Basis, Detrend, Harmonic, HarmonicOperand, Power, Wavelength,
};
use kin_compiler::ir::{
    Component, ErrorModel, FrameKind, FrameRef, JointKind, Machine, Scalar, Shape, Term, Var,
};

use super::graph::{Cmp, Dst, Graph, Id, Src};
use super::JitError;
use crate::engine::Observed;
use crate::interp::frame_order;

/// Which function a graph is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// Error (6) and nominal position (3) into `out`.
    Error,
    /// As `Error`, plus the 6 × n β-Jacobian into `jac`.
    Jacobian,
    /// Nominal position (3) and rotation (9) into `out`, the joint Jacobian into `jac`, one
    /// 6-vector per axis.
    Nominal,
}

/// Checks every index the generated code will use, so that the code can never read or write
/// outside the buffers whose lengths the safe API checks. A lowered machine is valid by
/// construction; this guards against a hand-built or deserialised one.
pub(super) fn validate(m: &Machine) -> Result<(), JitError> {
    let bad = |message: String| Err(JitError::Model { message });
    if m.tools.is_empty() {
        return bad("the machine has no tool".into());
    }
    for (chain, elements) in [("tool", &m.tool_chain), ("workpiece", &m.workpiece_chain)] {
        for (k, e) in elements.iter().enumerate() {
            if e.axis >= m.axes.len() {
                return bad(format!(
                    "element {k} of the {chain} chain uses axis {}, but there are {}",
                    e.axis,
                    m.axes.len()
                ));
            }
        }
    }
    for (i, l) in m.lags.iter().enumerate() {
        if !l.warmup && l.input >= m.inputs.len() {
            return bad(format!(
                "lag {i} reads input {}, but there are {}",
                l.input,
                m.inputs.len()
            ));
        }
    }
    let n = m.coefficients.len();
    // Byte offsets into the Jacobian are 32-bit immediates.
    if 6usize.saturating_mul(n.max(m.axes.len())).saturating_mul(8) >= i32::MAX as usize {
        return bad(format!("{n} coefficients are too many for one function"));
    }
    let mut owner = vec![false; n];
    for (e, model) in m.errors.iter().enumerate() {
        let ok = match model.frame {
            FrameRef::Tool(k) => k < m.tool_chain.len(),
            FrameRef::Workpiece(k) => k < m.workpiece_chain.len(),
            FrameRef::ToolEnd(Some(i)) => i < m.tools.len(),
            FrameRef::ToolEnd(None) | FrameRef::WorkpieceEnd => true,
        };
        if !ok {
            return bad(format!(
                "error model {e} refers to a frame the machine does not have"
            ));
        }
        for term in &model.terms {
            check_scalar(m, &term.scale)?;
            let mut size = 1usize;
            for f in &term.factors {
                check_var(m, f.var)?;
                if let Basis::Periodic {
                    wavelength: Wavelength::Fitted(p),
                    ..
                }
                | Basis::Fourier {
                    wavelength: Some(Wavelength::Fitted(p)),
                    ..
                } = &f.basis
                {
                    if p.index >= m.nonlinear.len() {
                        return bad(format!(
                            "a wavelength reads non-linear parameter {}, but there are {}",
                            p.index,
                            m.nonlinear.len()
                        ));
                    }
                }
                size = size.saturating_mul(f.basis.size());
            }
            if term.coefficients == 0 {
                continue;
            }
            let end = term
                .first
                .checked_add(term.coefficients)
                .filter(|&end| end <= n);
            if size != term.coefficients || end.is_none() {
                return bad(format!("a term of error model {e} has {} coefficients from {}, its factors give {size} and there are {n}", term.coefficients, term.first));
            }
            for slot in owner.iter_mut().skip(term.first).take(term.coefficients) {
                if std::mem::replace(slot, true) {
                    return bad(format!("coefficient {} belongs to two terms", term.first));
                }
            }
        }
    }
    Ok(())
}

fn check_var(m: &Machine, v: Var) -> Result<(), JitError> {
    let ok = match v {
        Var::Axis(i) | Var::Direction(i) => i < m.axes.len(),
        Var::Input(i) => i < m.inputs.len(),
        Var::Lag(i) => i < m.lags.len(),
        Var::Time => true,
    };
    if ok {
        Ok(())
    } else {
        Err(JitError::Model {
            message: format!("the variable {v:?} does not exist in the machine"),
        })
    }
}

fn check_scalar(m: &Machine, s: &Scalar) -> Result<(), JitError> {
    match s {
        Scalar::Num(_) => Ok(()),
        Scalar::Var(v) => check_var(m, *v),
        Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => check_scalar(m, a),
        Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
            check_scalar(m, a)?;
            check_scalar(m, b)
        }
    }
}

type Mat = [[Id; 3]; 3];
type Vec3 = [Id; 3];

/// A rigid transform as graph nodes: rotation block and translation column (eq. 2.2 without
/// its constant bottom row).
#[derive(Debug, Clone, Copy)]
struct Rigid {
    r: Mat,
    t: Vec3,
}

/// A frame as the F-matrix needs it: `sign·R(wr→k)` and the Abbe arm `a` from its origin to
/// the tool origin, both in wr axes.
#[derive(Debug, Clone, Copy)]
struct FrameF {
    r: Mat,
    arm: Vec3,
}

/// Coefficients per generated function at most. Cranelift's register allocator costs more
/// than linearly in the length of one straight-line function (at 10 000 coefficients one
/// function took 9.5 s to compile); past this size the error and Jacobian functions are built
/// as several pieces called in turn, each recomputing the kinematics (a few hundred
/// instructions), so compile time grows linearly with the model (1.5 s at 10 000 then; pieces
/// of 512 or 256 measured no faster since). A model of at most this many coefficients has one
/// function per kind, the same code as without pieces.
pub(super) const PIECE: usize = 1024;

/// Slot of `out` (past the 9 the functions return) that carries an error model's running sum
/// from one piece to the next when a piece ends inside the model.
const CARRY: usize = 9;

/// Builds the graphs of `kind` for `m`: one, or for the error functions of a model of more
/// than [`PIECE`] coefficients, several to be called in order on the same arguments.
/// `tool_rotation` is the tools' common rotation when they all share one (it is then folded in
/// as constants), else `None` and it is loaded with the tool offset.
///
/// The error functions compute and store only the `observed` components: error component `c`
/// in `out[c]` as always, its Jacobian row as row `observed.row(c)` of a compact
/// `observed.rows() × n` block. Dropping a row drops only stores, so every kept value is
/// computed by the same operations in the same order as with all six (bit for bit equal), and
/// what fed only the dropped rows is never emitted (`Graph::live`).
pub(super) fn build(
    m: &Machine,
    kind: Kind,
    tool_rotation: Option<[[f64; 3]; 3]>,
    observed: Observed,
) -> Vec<Graph> {
    match kind {
        Kind::Error | Kind::Jacobian => errors(m, kind == Kind::Jacobian, tool_rotation, observed),
        Kind::Nominal => {
            let mut b = Builder {
                g: Graph::default(),
                m,
            };
            let kin = b.kinematics(tool_rotation);
            b.nominal(&kin);
            vec![b.g]
        }
    }
}

/// One generated function under construction: its graph and the kinematics it starts from.
struct Piece<'m> {
    b: Builder<'m>,
    kin: Kinematics,
    /// Coefficients whose Jacobian entries or products this piece computes.
    size: usize,
}

impl<'m> Piece<'m> {
    fn new(m: &'m Machine, tool_rotation: Option<[[f64; 3]; 3]>) -> Piece<'m> {
        let mut b = Builder {
            g: Graph::default(),
            m,
        };
        let kin = b.kinematics(tool_rotation);
        Piece { b, kin, size: 0 }
    }

    /// The F-matrix column of `model`, with the task sign.
    fn column(&mut self, model: &ErrorModel, sign: f64) -> Option<[Id; 6]> {
        let f = *Builder::frame(&self.kin, model.frame)?;
        let col = self.b.column(&f, model.component);
        Some(if sign < 0.0 {
            col.map(|v| self.b.g.neg(v))
        } else {
            col
        })
    }
}

/// The error (eq. 2.24 with the task sign of eq. 2.31/2.34), optionally the β-Jacobian, as
/// one graph or (past [`PIECE`] coefficients) several.
fn errors(
    m: &Machine,
    jacobian: bool,
    tool_rotation: Option<[[f64; 3]; 3]>,
    observed: Observed,
) -> Vec<Graph> {
    let n = m.coefficients.len();
    let sign = m.task.sign();
    // Several pieces keep the error's running sums in `out` (each piece adds to them); one
    // piece keeps the error-only function's sums in registers (see below).
    let pieces = n > PIECE;
    // Frame by frame, so that a frame's rotation and arm are live only while its components
    // are being written.
    let mut models: Vec<&ErrorModel> = m.errors.iter().collect();
    models.sort_by_key(|e| frame_order(e.frame));
    let mut written = vec![false; n];
    // Running sums, brought up to date after every component so that no component's column
    // outlives it. With at most three rows they are kept in registers, which leaves enough
    // for the columns and basis values (3–5 % faster than through `out`, the same code
    // compiled both ways in one process). Six sums and six column splats are more than the
    // 16 vector registers hold with everything else: the register allocator spilled and
    // reloaded the sums and the frame's rotation around every component, and the six-row
    // function outgrew the first-level instruction cache. Through `out` (a load, an add and
    // a store per row and component) the 5-axis example's six-row function has 552 moves to
    // and from the stack instead of 732, 4 % less code, and runs 3–5 % faster through the C
    // ABI, both ways in one process (spec/performance.md). Several pieces hand their sums on
    // in `out` in any case.
    let memory = pieces || (jacobian && observed.rows() > 3);
    let mut done = Vec::new();
    let mut piece = Piece::new(m, tool_rotation);
    // Used only with a single piece, whose graph this is.
    let zero = piece.b.c(0.0);
    let mut error = [zero; 6];
    let mut started = [false; 6];
    for model in models {
        let Some(mut col) = piece.column(model, sign) else {
            continue;
        };
        // Another tool's frame contributes nothing; selecting after the product keeps a NaN
        // in a variable only that tool's model reads from leaking in through 0·NaN.
        let only = match model.frame {
            FrameRef::ToolEnd(Some(i)) => Some(i),
            _ => None,
        };
        // The component's value Σ v·β (+ fixed terms), as a running sum kept current after
        // each coefficient, so each basis value dies right after its six stores.
        let mut value: Option<Id> = None;
        let accumulate = |g: &mut Graph, value: &mut Option<Id>, x: Id| {
            let v = match *value {
                None => x,
                Some(a) => g.add(a, x),
            };
            g.eval(v);
            *value = Some(v);
        };
        let mut pending: Option<(usize, Id)> = None;
        for term in &model.terms {
            let mut values = piece.b.term(term);
            if term.coefficients == 0 {
                if let Some(&v) = values.first() {
                    accumulate(&mut piece.b.g, &mut value, v);
                }
                continue;
            }
            for k in 0..term.coefficients {
                if pieces && piece.size >= PIECE {
                    // Cut here: this piece writes what it has and hands the running sum on
                    // in `out`; the next recomputes the column and the term's values (the
                    // same operations, so the same numbers) and goes on adding to it.
                    if let Some((i, u)) = pending.take() {
                        piece.b.jac_single(&col, only, observed, n, i, u);
                    }
                    if let Some(v) = value {
                        piece.b.g.store(Dst::Out, CARRY, v);
                    }
                    done.push(
                        std::mem::replace(&mut piece, Piece::new(m, tool_rotation))
                            .b
                            .g,
                    );
                    let Some(c) = piece.column(model, sign) else {
                        break;
                    };
                    col = c;
                    values = piece.b.term(term);
                    if value.is_some() {
                        value = Some(piece.b.g.load(Src::Out, CARRY));
                    }
                }
                let Some(&v) = values.get(k) else {
                    break;
                };
                piece.size += 1;
                let j = term.first + k;
                if jacobian {
                    if let Some(w) = written.get_mut(j) {
                        *w = true;
                    }
                    // Adjacent coefficients of one component share the column: their entries
                    // go out in pairs (another tool's gated ones one by one).
                    match pending.take() {
                        Some((i, u)) if i + 1 == j && only.is_none() => {
                            for (row, r) in observed.components().enumerate() {
                                let c = col[r];
                                piece.b.g.store_pair(Dst::Jac, row * n + i, c, u, v);
                            }
                        }
                        other => {
                            if let Some((i, u)) = other {
                                piece.b.jac_single(&col, only, observed, n, i, u);
                            }
                            pending = Some((j, v));
                        }
                    }
                }
                let b = piece.b.g.load(Src::Beta, j);
                let vb = piece.b.g.mul(v, b);
                accumulate(&mut piece.b.g, &mut value, vb);
            }
        }
        if let Some((i, u)) = pending.take() {
            piece.b.jac_single(&col, only, observed, n, i, u);
        }
        let g = &mut piece.b.g;
        let value = value.unwrap_or_else(|| g.konst(0.0));
        for (r, &c) in col.iter().enumerate() {
            if !observed.contains(r) {
                continue;
            }
            let p = g.mul(c, value);
            let p = match only {
                Some(i) => g.if_tool(i, p),
                None => p,
            };
            if g.value(p) == Some(0.0) {
                continue;
            }
            match (memory, started.get_mut(r), error.get_mut(r)) {
                (true, Some(s @ false), _) => {
                    *s = true;
                    g.store(Dst::Out, r, p);
                }
                (true, ..) => g.add_to(Dst::Out, r, p),
                // With the Jacobian a sum starts at its first product, as it does in `out`
                // (several pieces), so that every way of computing a row gives its bits
                // (`0 + p` would turn a −0 into +0).
                (false, Some(s @ false), Some(e)) if jacobian => {
                    *s = true;
                    *e = p;
                }
                (false, _, Some(e)) => {
                    *e = g.add(*e, p);
                    g.eval(*e);
                }
                (false, _, None) => {}
            }
        }
    }
    let g = &mut piece.b.g;
    let zero = g.konst(0.0);
    if jacobian {
        for (j, _) in written.iter().enumerate().filter(|(_, w)| !**w) {
            for row in 0..observed.rows() {
                g.store(Dst::Jac, row * n + j, zero);
            }
        }
    }
    for (r, e) in error.into_iter().enumerate() {
        if !observed.contains(r) {
            continue;
        }
        // With several pieces `error` was never used (and its zeros belong to the first).
        match (memory, started.get(r).copied().unwrap_or(false)) {
            (true, true) => {}
            (true, false) => g.store(Dst::Out, r, zero),
            (false, _) => g.store(Dst::Out, r, e),
        }
    }
    for (i, &p) in piece.kin.position.iter().enumerate() {
        g.store(Dst::Out, 6 + i, p);
    }
    done.push(piece.b.g);
    done
}

/// The per-pose kinematic quantities every function starts from.
struct Kinematics {
    tool_frames: Vec<FrameF>,
    workpiece_frames: Vec<FrameF>,
    tool_end: FrameF,
    workpiece_end: FrameF,
    /// Nominal tool location in wr: position and `R(wr→tl)`.
    position: Vec3,
    rotation: Mat,
}

struct Builder<'m> {
    g: Graph,
    m: &'m Machine,
}

impl Builder<'_> {
    fn c(&mut self, v: f64) -> Id {
        self.g.konst(v)
    }

    fn constant_rigid(&mut self, r: [[f64; 3]; 3], t: [f64; 3]) -> Rigid {
        let r = r.map(|row| row.map(|v| self.g.konst(v)));
        let t = t.map(|v| self.g.konst(v));
        Rigid { r, t }
    }

    fn identity(&mut self) -> Rigid {
        self.constant_rigid(
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0; 3],
        )
    }

    /// `Σ_k a_k b_k` in index order, as a matrix–vector product element.
    fn dot(&mut self, a: [Id; 3], b: [Id; 3]) -> Id {
        let p = [0, 1, 2].map(|k| self.g.mul(a[k], b[k]));
        self.g.sum(p)
    }

    fn mat_mul(&mut self, a: &Mat, b: &Mat) -> Mat {
        let mut out = *a;
        for (i, row) in out.iter_mut().enumerate() {
            for (j, o) in row.iter_mut().enumerate() {
                *o = self.dot(a[i], [b[0][j], b[1][j], b[2][j]]);
            }
        }
        out
    }

    fn mat_vec(&mut self, a: &Mat, v: &Vec3) -> Vec3 {
        [0, 1, 2].map(|i| self.dot(a[i], *v))
    }

    fn transpose(a: &Mat) -> Mat {
        [0, 1, 2].map(|i| [a[0][i], a[1][i], a[2][i]])
    }

    fn vec_sub(&mut self, a: &Vec3, b: &Vec3) -> Vec3 {
        [0, 1, 2].map(|i| self.g.sub(a[i], b[i]))
    }

    /// `a · b` in homogeneous form (`Rigid::then` of the kinematics).
    fn then(&mut self, a: &Rigid, b: &Rigid) -> Rigid {
        let r = self.mat_mul(&a.r, &b.r);
        let rt = self.mat_vec(&a.r, &b.t);
        let t = [0, 1, 2].map(|i| self.g.add(a.t[i], rt[i]));
        Rigid { r, t }
    }

    /// Postmultiplies `g` by the joint motion `J(q)` (spec/kinematics.md): a translation `q·u`, or
    /// Rodrigues' rotation `cI + s[u]× + (1−c)uuᵀ` about the unit axis `u`.
    fn joint(&mut self, g: &mut Rigid, kind: JointKind, u: [f64; 3], q: Id) {
        match kind {
            JointKind::Prismatic => {
                let uq = u.map(|ui| {
                    let ui = self.g.konst(ui);
                    self.g.mul(ui, q)
                });
                let d = self.mat_vec(&g.r, &uq);
                g.t = [0, 1, 2].map(|i| self.g.add(g.t[i], d[i]));
            }
            JointKind::Revolute => {
                let (s, c) = (self.g.sin(q), self.g.cos(q));
                let one = self.c(1.0);
                let omc = self.g.sub(one, c);
                let k = cross_matrix_f(u);
                let mut r = [[one; 3]; 3];
                for (i, row) in r.iter_mut().enumerate() {
                    for (j, o) in row.iter_mut().enumerate() {
                        let id = self.c(if i == j { 1.0 } else { 0.0 });
                        let ic = self.g.mul(id, c);
                        let kij = self.c(k[i][j]);
                        let ks = self.g.mul(kij, s);
                        let uu = self.c(u[i] * u[j]);
                        let uuc = self.g.mul(uu, omc);
                        let a = self.g.add(ic, ks);
                        *o = self.g.add(a, uuc);
                    }
                }
                g.r = self.mat_mul(&g.r, &r);
            }
        }
    }

    /// Runs one chain from the base: each frame's base location (moving: after its joint,
    /// fixed: before it, eq. 2.35–2.38) and the location before the end shape.
    fn chain(&mut self, elements: &[kin_compiler::ir::Element]) -> (Vec<Rigid>, Rigid) {
        let mut g = self.identity();
        let mut frames = Vec::with_capacity(elements.len());
        for e in elements {
            let (r, t) = shape_transform(&e.shape);
            let s = self.constant_rigid(r, t);
            let before = self.then(&g, &s);
            g = before;
            if let Some(axis) = self.m.axes.get(e.axis) {
                let q = self.g.load(Src::Q, e.axis);
                self.joint(&mut g, axis.kind, axis.direction, q);
            }
            frames.push(match e.frame {
                FrameKind::Moving => g,
                FrameKind::Fixed => before,
            });
        }
        (frames, g)
    }

    fn kinematics(&mut self, tool_rotation: Option<[[f64; 3]; 3]>) -> Kinematics {
        let m = self.m;
        let (tool_frames, tool_last) = self.chain(&m.tool_chain);
        let (wp_frames, wp_last) = self.chain(&m.workpiece_chain);
        let tool_shape = Rigid {
            r: match tool_rotation {
                Some(r) => r.map(|row| row.map(|v| self.g.konst(v))),
                None => [0, 1, 2].map(|i| [0, 1, 2].map(|j| self.g.load(Src::ToolTf, 3 * i + j))),
            },
            t: [0, 1, 2].map(|i| self.g.load(Src::ToolTf, 9 + i)),
        };
        let tool_base = self.then(&tool_last, &tool_shape);
        let (r, t) = shape_transform(&m.workpiece);
        let wp_shape = self.constant_rigid(r, t);
        let wr_base = self.then(&wp_last, &wp_shape);

        let wr_rot_t = Self::transpose(&wr_base.r);
        let rotation = self.mat_mul(&wr_rot_t, &tool_base.r);
        let rel = self.vec_sub(&tool_base.t, &wr_base.t);
        let position = self.mat_vec(&wr_rot_t, &rel);

        let frame_f = |b: &mut Self, frame: &Rigid, negate: bool| {
            let mut r = b.mat_mul(&wr_rot_t, &frame.r);
            if negate {
                r = r.map(|row| row.map(|v| b.g.neg(v)));
            }
            let rel = b.vec_sub(&tool_base.t, &frame.t);
            let arm = b.mat_vec(&wr_rot_t, &rel);
            FrameF { r, arm }
        };
        let tool_frames = tool_frames
            .iter()
            .map(|f| frame_f(self, f, false))
            .collect();
        let workpiece_frames = wp_frames.iter().map(|f| frame_f(self, f, true)).collect();
        let zero = self.c(0.0);
        let minus_one = self.c(-1.0);
        let tool_end = FrameF {
            r: rotation,
            arm: [zero; 3],
        };
        let workpiece_end = FrameF {
            r: [0, 1, 2].map(|i| [0, 1, 2].map(|j| if i == j { minus_one } else { zero })),
            arm: position,
        };
        Kinematics {
            tool_frames,
            workpiece_frames,
            tool_end,
            workpiece_end,
            position,
            rotation,
        }
    }

    /// Column `c` of `F = [[r, −[a]× r], [0, r]]` (`r` already carries the chain's sign).
    fn column(&mut self, f: &FrameF, c: Component) -> [Id; 6] {
        let zero = self.c(0.0);
        let j = c.index() % 3;
        let rj = [f.r[0][j], f.r[1][j], f.r[2][j]];
        if !c.is_rotation() {
            return [rj[0], rj[1], rj[2], zero, zero, zero];
        }
        // −[a]× r_j = r_j × a. Each entry is one difference of two products, a single rounding
        // whatever the order, so this is bit for bit the interpreter's `−(cross_matrix · r)`
        // (whose third product is with an exact zero), without its negations.
        let a = f.arm;
        let cross = |g: &mut Graph, p: Id, q: Id, r: Id, t: Id| {
            let x = g.mul(p, q);
            let y = g.mul(r, t);
            g.sub(x, y)
        };
        let top = [
            cross(&mut self.g, rj[1], a[2], rj[2], a[1]),
            cross(&mut self.g, rj[2], a[0], rj[0], a[2]),
            cross(&mut self.g, rj[0], a[1], rj[1], a[0]),
        ];
        [top[0], top[1], top[2], rj[0], rj[1], rj[2]]
    }

    fn frame(kin: &Kinematics, frame: FrameRef) -> Option<&FrameF> {
        match frame {
            FrameRef::Tool(k) => kin.tool_frames.get(k),
            FrameRef::Workpiece(k) => kin.workpiece_frames.get(k),
            FrameRef::ToolEnd(_) => Some(&kin.tool_end),
            FrameRef::WorkpieceEnd => Some(&kin.workpiece_end),
        }
    }

    fn var(&mut self, v: Var) -> Id {
        match v {
            Var::Axis(i) => self.g.load(Src::Q, i),
            Var::Input(i) => self.g.load(Src::Inputs, i),
            Var::Lag(i) => self.g.load(Src::Lags, i),
            Var::Time => self.g.load(Src::Time, 0),
            Var::Direction(i) => self.g.load(Src::Dirs, i),
        }
    }

    /// A known scalar, operation for operation as `interp::scalar`.
    fn scalar(&mut self, s: &Scalar) -> Id {
        match s {
            Scalar::Num(x) => self.c(*x),
            Scalar::Var(v) => self.var(*v),
            Scalar::Neg(a) => {
                let a = self.scalar(a);
                self.g.neg(a)
            }
            Scalar::Add(a, b) => {
                let (a, b) = (self.scalar(a), self.scalar(b));
                self.g.add(a, b)
            }
            Scalar::Sub(a, b) => {
                let (a, b) = (self.scalar(a), self.scalar(b));
                self.g.sub(a, b)
            }
            Scalar::Mul(a, b) => {
                let (a, b) = (self.scalar(a), self.scalar(b));
                self.g.mul(a, b)
            }
            Scalar::Div(a, b) => {
                let (a, b) = (self.scalar(a), self.scalar(b));
                self.g.div(a, b)
            }
            Scalar::Sin(a) => {
                let a = self.scalar(a);
                self.g.sin(a)
            }
            Scalar::Cos(a) => {
                let a = self.scalar(a);
                self.g.cos(a)
            }
        }
    }

    /// The variable of a basis factor; a continuous axis is reduced to one turn with
    /// `rem_euclid(2π)` = `r = x % 2π; if r < 0 { r + 2π } else { r }` (spec: factors, variables).
    fn factor_var(&mut self, v: Var) -> Id {
        let x = self.var(v);
        let continuous =
            matches!(v, Var::Axis(a) if self.m.axes.get(a).is_some_and(|axis| axis.continuous));
        if !continuous {
            return x;
        }
        let tau = self.c(TAU);
        let r = self.g.fmod(x, tau);
        let zero = self.c(0.0);
        let wrapped = self.g.add(r, tau);
        let turn = self.g.select(Cmp::Gt, zero, r, wrapped, r);
        // Positions within the first turn are their own reduction: the generated code then
        // reuses the joint's `sincos` (emit.rs), the same numbers as a call of its own.
        self.g.usually_equal(turn, x);
        turn
    }

    /// `(x − lo)/(hi − lo)`.
    fn normalise(&mut self, x: Id, lo: f64, hi: f64) -> Id {
        let lo_id = self.c(lo);
        let d = self.g.sub(x, lo_id);
        let w = self.c(hi - lo);
        self.g.div(d, w)
    }

    /// `u^n` as `((1·u)·u)…` (`basis::ipow`).
    fn ipow(&mut self, u: Id, n: u32) -> Id {
        let mut r = self.c(1.0);
        for _ in 0..n {
            r = self.g.mul(r, u);
        }
        r
    }

    /// `u^l` or `(u − t)_+^l` (eq. 3.3), as `Power::value`.
    ///
    /// `Power::value` selects (`if u > t { (u − t)^l } else { 0 }`). For `l ≥ 1` this computes
    /// `max(u − t, 0)^l` instead ([`super::graph::Node::PosPart`]), the same number (`u > t`
    /// exactly when `u − t > 0`, and `0^l` is 0; a NaN `u` gives 0 in both) without a branch
    /// on the data, which random states mispredict half the time.
    fn power(&mut self, p: Power, u: Id) -> Id {
        match p.knot {
            None => self.ipow(u, p.power),
            Some(t) => {
                let t = self.c(t);
                let d = self.g.sub(u, t);
                if p.power == 0 {
                    let (one, zero) = (self.c(1.0), self.c(0.0));
                    return self.g.select(Cmp::Gt, u, t, one, zero);
                }
                let clamped = self.g.pos_part(d);
                self.ipow(clamped, p.power)
            }
        }
    }

    /// `(sin, cos)` of harmonic `harmonics[i]` of the angle `x`, obtained as
    /// `basis::harmonic_step` says (as `Basis::eval` does). `done[j]` holds harmonic `j` once
    /// built: without it each harmonic rebuilt its whole chain of operands down to the
    /// fundamental, and looked each step up again, which at 10⁴ coefficients was a third of
    /// the compile time (the graph is hash-consed, so the nodes are the same either way).
    fn harmonic(
        &mut self,
        harmonics: &[u32],
        i: usize,
        x: Id,
        done: &mut [Option<(Id, Id)>],
    ) -> (Id, Id) {
        if let Some(Some(known)) = done.get(i) {
            return *known;
        }
        let result = match harmonic_step(harmonics, i) {
            Harmonic::Fundamental => (self.g.sin(x), self.g.cos(x)),
            Harmonic::Direct => {
                let h = harmonics.get(i).copied().unwrap_or(0);
                let hc = self.c(f64::from(h));
                let a = self.g.mul(hc, x);
                (self.g.sin(a), self.g.cos(a))
            }
            Harmonic::Sum(a, b) => {
                let mut operand = |o: HarmonicOperand, done: &mut [Option<(Id, Id)>]| match o {
                    HarmonicOperand::Fundamental => (self.g.sin(x), self.g.cos(x)),
                    HarmonicOperand::Listed(j) => self.harmonic(harmonics, j, x, done),
                };
                let (sa, ca) = operand(a, done);
                let (sb, cb) = operand(b, done);
                // `basis::angle_sum`: (sa·cb + ca·sb, ca·cb − sa·sb).
                let (sa_cb, ca_sb) = (self.g.mul(sa, cb), self.g.mul(ca, sb));
                let (ca_cb, sa_sb) = (self.g.mul(ca, cb), self.g.mul(sa, sb));
                (self.g.add(sa_cb, ca_sb), self.g.sub(ca_cb, sa_sb))
            }
        };
        if let Some(slot) = done.get_mut(i) {
            *slot = Some(result);
        }
        result
    }

    /// The values of `basis` at `x`, as `Basis::eval` computes them (thesis §3.2.2–3.2.5).
    fn basis(&mut self, basis: &Basis, x: Id) -> Vec<Id> {
        match basis {
            Basis::Const => vec![self.c(1.0)],
            Basis::Sign => vec![x],
            Basis::Linear { lo, hi } => {
                let s = self.normalise(x, *lo, *hi);
                vec![self.centred(s)]
            }
            Basis::Legendre { lo, hi, degree } => {
                // Bonnet: (n+1) P_{n+1} = (2n+1) u P_n − n P_{n−1}.
                let s = self.normalise(x, *lo, *hi);
                let u = self.centred(s);
                let mut previous = self.c(1.0);
                let mut current = u;
                let mut out = Vec::with_capacity(*degree as usize);
                for n in 1..=*degree {
                    out.push(current);
                    let n = f64::from(n);
                    let a = self.c(2.0 * n + 1.0);
                    let au = self.g.mul(a, u);
                    let auc = self.g.mul(au, current);
                    let nc = self.c(n);
                    let np = self.g.mul(nc, previous);
                    let num = self.g.sub(auc, np);
                    let den = self.c(n + 1.0);
                    let next = self.g.div(num, den);
                    previous = current;
                    current = next;
                }
                out
            }
            Basis::Spline {
                lo,
                hi,
                detrend,
                functions,
                ..
            } => {
                let s = self.normalise(x, *lo, *hi);
                let rev = match detrend {
                    Detrend::OncePerRev => {
                        let mid = self.c(lo + 0.5 * (hi - lo));
                        let u = self.g.sub(x, mid);
                        Some((self.g.cos(u), self.g.sin(u)))
                    }
                    Detrend::None | Detrend::Line => None,
                };
                functions
                    .iter()
                    .map(|f| {
                        let g = self.power(f.g, s);
                        let (t0, t1) = (self.c(f.trend[0]), self.c(f.trend[1]));
                        match (detrend, rev) {
                            (Detrend::Line, _) => {
                                let t1s = self.g.mul(t1, s);
                                let line = self.g.add(t0, t1s);
                                self.g.sub(g, line)
                            }
                            (Detrend::OncePerRev, Some((c, sn))) => {
                                let a = self.g.mul(t0, c);
                                let b = self.g.mul(t1, sn);
                                let ga = self.g.sub(g, a);
                                self.g.sub(ga, b)
                            }
                            _ => g,
                        }
                    })
                    .collect()
            }
            Basis::Fourier {
                harmonics,
                wavelength,
            } => {
                // The fundamental's angle: x (rad), or 2π x/λ (`Basis::eval`).
                let x = match wavelength {
                    None => x,
                    Some(w) => {
                        let tau = match w {
                            Wavelength::Fixed(t) => self.c(*t),
                            Wavelength::Fitted(p) => self.g.load(Src::Nonlinear, p.index),
                        };
                        let two_pi = self.c(std::f64::consts::TAU);
                        let a = self.g.mul(two_pi, x);
                        self.g.div(a, tau)
                    }
                };
                let mut out = Vec::with_capacity(2 * harmonics.len());
                let mut done = vec![None; harmonics.len()];
                for i in 0..harmonics.len() {
                    let (s, c) = self.harmonic(harmonics, i, x, &mut done);
                    out.push(c);
                    out.push(s);
                }
                out
            }
            Basis::Periodic {
                wavelength,
                phase,
                functions,
                ..
            } => {
                // w = frac((x − φ)/τ) ∈ [0, 1) (eq. 3.13, `basis::wavelength_fraction`).
                let tau = match wavelength {
                    Wavelength::Fixed(t) => self.c(*t),
                    Wavelength::Fitted(p) => self.g.load(Src::Nonlinear, p.index),
                };
                let ph = self.c(*phase);
                let d = self.g.sub(x, ph);
                let y = self.g.div(d, tau);
                let fl = self.g.floor(y);
                let w = self.g.sub(y, fl);
                let (one, zero) = (self.c(1.0), self.c(0.0));
                let w = self.g.select(Cmp::Ge, w, one, zero, w);
                functions
                    .iter()
                    .map(|f| {
                        // v(w) = g(w) − w·(α1 + w·(α2 + …)) (eq. 3.12, Horner as `periodic_value`).
                        let mut acc = self.c(0.0);
                        for a in f.alpha.iter().rev() {
                            let aw = self.g.mul(acc, w);
                            let ac = self.c(*a);
                            acc = self.g.add(aw, ac);
                        }
                        let g = self.power(f.g, w);
                        let corr = self.g.mul(acc, w);
                        self.g.sub(g, corr)
                    })
                    .collect()
            }
        }
    }

    /// `2s − 1`.
    fn centred(&mut self, s: Id) -> Id {
        let two = self.c(2.0);
        let one = self.c(1.0);
        let t = self.g.mul(two, s);
        self.g.sub(t, one)
    }

    /// The tensor-product values of a term, row-major: `((scale·f1[i1])·f2[i2])·…`, the order
    /// of `Interpreter::term_values`.
    fn term(&mut self, term: &Term) -> Vec<Id> {
        let scale = self.scalar(&term.scale);
        let mut values = vec![scale];
        for f in &term.factors {
            let x = self.factor_var(f.var);
            let fv = self.basis(&f.basis, x);
            let mut next = Vec::with_capacity(values.len() * fv.len());
            for &a in &values {
                for &v in &fv {
                    next.push(self.g.mul(a, v));
                }
            }
            values = next;
        }
        values
    }

    /// The observed Jacobian entries of coefficient `j` with basis value `v`, one by one.
    fn jac_single(
        &mut self,
        col: &[Id; 6],
        only: Option<usize>,
        observed: Observed,
        n: usize,
        j: usize,
        v: Id,
    ) {
        for (row, r) in observed.components().enumerate() {
            let p = self.g.mul(col[r], v);
            let p = match only {
                Some(i) => self.g.if_tool(i, p),
                None => p,
            };
            self.g.store(Dst::Jac, row * n + j, p);
        }
    }

    /// The nominal location and its joint Jacobian (`FirstOrderModel::nominal_jacobian`): a
    /// joint motion `dq` of element k is an error `u·dq` of frame k, so column j is
    /// `Σ F_k·(u, 0)` (prismatic) or `Σ F_k·(0, u)` (revolute) over the elements axis j drives.
    fn nominal(&mut self, kin: &Kinematics) {
        let m = self.m;
        let axes = m.axes.len();
        let mut columns: Vec<[Vec<Id>; 6]> = vec![Default::default(); axes];
        let chains = [
            (&m.tool_chain, &kin.tool_frames),
            (&m.workpiece_chain, &kin.workpiece_frames),
        ];
        for (elements, frames) in chains {
            for (e, f) in elements.iter().zip(frames) {
                let Some(axis) = m.axes.get(e.axis) else {
                    continue;
                };
                let components = match axis.kind {
                    JointKind::Prismatic => [Component::Tx, Component::Ty, Component::Tz],
                    JointKind::Revolute => [Component::Rx, Component::Ry, Component::Rz],
                };
                let cols = components.map(|c| self.column(f, c));
                for r in 0..6 {
                    let terms: Vec<Id> = cols
                        .iter()
                        .zip(axis.direction)
                        .map(|(col, u)| {
                            let u = self.c(u);
                            self.g.mul(col[r], u)
                        })
                        .collect();
                    let v = self.g.sum(terms);
                    if let Some(slot) = columns.get_mut(e.axis).and_then(|c| c.get_mut(r)) {
                        slot.push(v);
                    }
                }
            }
        }
        for (a, col) in columns.into_iter().enumerate() {
            for (r, parts) in col.into_iter().enumerate() {
                let v = self.g.sum(parts);
                self.g.store(Dst::Jac, 6 * a + r, v);
            }
        }
        for (i, &p) in kin.position.iter().enumerate() {
            self.g.store(Dst::Out, i, p);
        }
        for i in 0..3 {
            for j in 0..3 {
                self.g.store(Dst::Out, 3 + 3 * i + j, kin.rotation[i][j]);
            }
        }
    }
}

/// `[u]×` of a constant vector.
fn cross_matrix_f(u: [f64; 3]) -> [[f64; 3]; 3] {
    [[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]]
}

/// Shape transform `S = Trans(t)·Rot_x(rx)·Rot_y(ry)·Rot_z(rz)` (spec/kinematics.md, eq. 2.8), the
/// closed form of `kinematics::shape_transform`, evaluated once at compile time.
pub(super) fn shape_transform(shape: &Shape) -> ([[f64; 3]; 3], [f64; 3]) {
    let [rx, ry, rz] = shape.rotation;
    let (sa, ca) = (libm::sin(rx), libm::cos(rx));
    let (sb, cb) = (libm::sin(ry), libm::cos(ry));
    let (sc, cc) = (libm::sin(rz), libm::cos(rz));
    (
        [
            [cb * cc, -cb * sc, sb],
            [ca * sc + sa * sb * cc, ca * cc - sa * sb * sc, -sa * cb],
            [sa * sc - ca * sb * cc, sa * cc + ca * sb * sc, ca * cb],
        ],
        shape.translation,
    )
}
