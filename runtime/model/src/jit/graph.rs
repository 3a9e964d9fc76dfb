//! A straight-line expression graph: the middle stage between the IR and Cranelift.
//!
//! Every value the generated code computes is a node; nodes are hash-consed, so a quantity built
//! twice (the same basis value in three components, `sin q` for a joint and a basis) exists once,
//! and constants are folded while the graph is built. Only the nodes that some output needs are
//! emitted (see `emit`), so building a quantity that turns out to be unused costs nothing at run
//! time.
//!
//! Folding keeps IEEE semantics wherever the interpreter could observe a difference: constant
//! operands are combined with the very operations the generated code would perform (and `sin`,
//! `cos`, `fmod` through the same `libm` functions), and the only algebraic identities used are
//! exact ones (`x·1 = x`, `x + 0 = x`, `x·(−1) = −x`, `−(−x) = x`), plus `x·0 = 0`, which holds
//! for every finite `x` — the state's variables are checked for NaN before a call, and a state at
//! infinity has no meaningful error anyway.

// Interning hashes every node built (hundreds of thousands at 10⁴ coefficients): SipHash's
// resistance to chosen keys buys nothing for keys the compiler makes itself, and it was a sixth
// of the compile time.
use rustc_hash::FxHashMap as HashMap;

/// Index of a node in its [`Graph`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(super) struct Id(u32);

impl Id {
    pub(super) fn index(self) -> usize {
        self.0 as usize
    }

    pub(super) fn new(index: usize) -> Id {
        Id(u32::try_from(index).unwrap_or(u32::MAX))
    }
}

/// The arrays of the argument block (`Args` in `mod.rs`) a load reads from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) enum Src {
    Q,
    Inputs,
    Lags,
    Dirs,
    Beta,
    Nonlinear,
    /// The selected tool's offset: rotation row-major (9), then translation (3).
    ToolTf,
    /// The scalar `time` field (index ignored).
    Time,
    /// `out`, read back where an earlier piece of the same function left a value (`lower`).
    Out,
}

/// The output arrays a store writes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) enum Dst {
    /// Error (6) and nominal position (3); or, for the nominal function, position (3) and
    /// rotation (9, row-major).
    Out,
    /// The 6 × n row-major Jacobian (β or joint).
    Jac,
}

/// Comparison of a [`Node::Select`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) enum Cmp {
    Gt,
    Ge,
}

impl Cmp {
    fn holds(self, a: f64, b: f64) -> bool {
        match self {
            Cmp::Gt => a > b,
            Cmp::Ge => a >= b,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) enum Node {
    /// An f64 constant, by its bits so that nodes can be hashed.
    Const(u64),
    Load(Src, u32),
    Add(Id, Id),
    Sub(Id, Id),
    Mul(Id, Id),
    Div(Id, Id),
    Neg(Id),
    Floor(Id),
    Sin(Id),
    Cos(Id),
    /// `max(a, 0)`: `a` where `0 < a`, else +0 (for a NaN too), without a branch (one
    /// `maxsd` in the generated code). Of `u − t` it is the interpreter's `if u > t` of a
    /// truncated power bit for bit: for finite `u` and `t`, `u − t > 0` exactly when `u > t`.
    PosPart(Id),
    /// `a % b` as Rust (and C's `fmod`) define it: exact, so any implementation agrees.
    Fmod(Id, Id),
    /// `if a CMP b { then } else { otherwise }`; false when either side is NaN, as in Rust.
    Select(Cmp, Id, Id, Id, Id),
    /// `if tool == i { x } else { 0 }`: errors of one tool's frame act only for that tool.
    IfTool(u32, Id),
}

/// What the generated function does, in order: store a value, or compute one at this point
/// (a schedule hint: a running sum is brought up to date after each component instead of
/// keeping every part alive until the final store).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Effect {
    Store(Dst, u32, Id),
    /// Stores `col·a` at `index` and `col·b` at `index + 1`: two Jacobian entries of one
    /// column, as one two-lane multiply and one 16-byte store.
    Pair(Dst, u32, Id, Id, Id),
    /// `dst[index] += value`, a running sum kept in memory.
    AddTo(Dst, u32, Id),
    Eval(Id),
}

/// Nodes in creation order (operands always precede their users) and the effects to perform.
#[derive(Debug, Default)]
pub(super) struct Graph {
    nodes: Vec<Node>,
    index: HashMap<Node, Id>,
    effects: Vec<Effect>,
    /// Values that usually equal another one at run time (see [`Graph::usually_equal`]).
    usually: HashMap<Id, Id>,
}

impl Graph {
    pub(super) fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    pub(super) fn effects(&self) -> &[Effect] {
        &self.effects
    }

    pub(super) fn node(&self, id: Id) -> Node {
        self.nodes
            .get(id.index())
            .copied()
            .unwrap_or(Node::Const(0))
    }

    /// Records that `x` usually holds the same number as `y` (a continuous axis's angle reduced
    /// to one turn is the angle itself whenever it is within the turn already): code that
    /// calls a function of `x` may then test for equality and take the result of `y`'s call.
    pub(super) fn usually_equal(&mut self, x: Id, y: Id) {
        if x != y {
            self.usually.insert(x, y);
        }
    }

    /// The value `x` usually equals, if one was recorded.
    pub(super) fn usual(&self, x: Id) -> Option<Id> {
        self.usually.get(&x).copied()
    }

    /// The node, if it was ever built (used to pair `sin x` with `cos x` into one call).
    pub(super) fn find(&self, node: &Node) -> Option<Id> {
        self.index.get(node).copied()
    }

    fn intern(&mut self, node: Node) -> Id {
        // A graph holds far fewer than 2³² nodes (the IR bounds knots, degrees and harmonics);
        // saturating keeps this total rather than wrapping.
        let next = Id(u32::try_from(self.nodes.len()).unwrap_or(u32::MAX));
        // One lookup for both outcomes: most nodes built are new.
        match self.index.entry(node) {
            std::collections::hash_map::Entry::Occupied(e) => *e.get(),
            std::collections::hash_map::Entry::Vacant(e) => {
                self.nodes.push(node);
                e.insert(next);
                next
            }
        }
    }

    pub(super) fn store(&mut self, dst: Dst, index: usize, value: Id) {
        let index = u32::try_from(index).unwrap_or(u32::MAX);
        self.effects.push(Effect::Store(dst, index, value));
    }

    pub(super) fn add_to(&mut self, dst: Dst, index: usize, value: Id) {
        let index = u32::try_from(index).unwrap_or(u32::MAX);
        self.effects.push(Effect::AddTo(dst, index, value));
    }

    pub(super) fn store_pair(&mut self, dst: Dst, index: usize, col: Id, a: Id, b: Id) {
        let index = u32::try_from(index).unwrap_or(u32::MAX);
        self.effects.push(Effect::Pair(dst, index, col, a, b));
    }

    /// Asks for `value` to be computed here, before the effects that follow.
    pub(super) fn eval(&mut self, value: Id) {
        if !matches!(self.node(value), Node::Const(_)) {
            self.effects.push(Effect::Eval(value));
        }
    }

    pub(super) fn konst(&mut self, v: f64) -> Id {
        self.intern(Node::Const(v.to_bits()))
    }

    pub(super) fn load(&mut self, src: Src, index: usize) -> Id {
        self.intern(Node::Load(src, u32::try_from(index).unwrap_or(u32::MAX)))
    }

    /// The constant value of a node, if it is one.
    pub(super) fn value(&self, id: Id) -> Option<f64> {
        match self.node(id) {
            Node::Const(bits) => Some(f64::from_bits(bits)),
            _ => None,
        }
    }

    fn is(&self, id: Id, v: f64) -> bool {
        self.value(id) == Some(v)
    }

    pub(super) fn add(&mut self, a: Id, b: Id) -> Id {
        if let (Some(x), Some(y)) = (self.value(a), self.value(b)) {
            return self.konst(x + y);
        }
        if self.is(a, 0.0) {
            return b;
        }
        if self.is(b, 0.0) {
            return a;
        }
        // IEEE addition is commutative, so one canonical order finds more common terms.
        self.intern(Node::Add(a.min(b), a.max(b)))
    }

    pub(super) fn sub(&mut self, a: Id, b: Id) -> Id {
        if let (Some(x), Some(y)) = (self.value(a), self.value(b)) {
            return self.konst(x - y);
        }
        if self.is(b, 0.0) {
            return a;
        }
        if self.is(a, 0.0) {
            return self.neg(b);
        }
        self.intern(Node::Sub(a, b))
    }

    pub(super) fn mul(&mut self, a: Id, b: Id) -> Id {
        if let (Some(x), Some(y)) = (self.value(a), self.value(b)) {
            return self.konst(x * y);
        }
        if self.is(a, 0.0) || self.is(b, 0.0) {
            return self.konst(0.0);
        }
        for (one, other) in [(a, b), (b, a)] {
            if self.is(one, 1.0) {
                return other;
            }
            if self.is(one, -1.0) {
                return self.neg(other);
            }
        }
        self.intern(Node::Mul(a.min(b), a.max(b)))
    }

    pub(super) fn div(&mut self, a: Id, b: Id) -> Id {
        if let (Some(x), Some(y)) = (self.value(a), self.value(b)) {
            return self.konst(x / y);
        }
        if self.is(b, 1.0) {
            return a;
        }
        self.intern(Node::Div(a, b))
    }

    pub(super) fn neg(&mut self, a: Id) -> Id {
        match self.node(a) {
            Node::Const(bits) => self.konst(-f64::from_bits(bits)),
            Node::Neg(x) => x,
            _ => self.intern(Node::Neg(a)),
        }
    }

    pub(super) fn floor(&mut self, a: Id) -> Id {
        match self.value(a) {
            Some(x) => self.konst(libm::floor(x)),
            None => self.intern(Node::Floor(a)),
        }
    }

    pub(super) fn sin(&mut self, a: Id) -> Id {
        match self.value(a) {
            Some(x) => self.konst(libm::sin(x)),
            None => self.intern(Node::Sin(a)),
        }
    }

    pub(super) fn cos(&mut self, a: Id) -> Id {
        match self.value(a) {
            Some(x) => self.konst(libm::cos(x)),
            None => self.intern(Node::Cos(a)),
        }
    }

    pub(super) fn pos_part(&mut self, a: Id) -> Id {
        match self.value(a) {
            Some(x) => self.konst(if 0.0 < x { x } else { 0.0 }),
            None => self.intern(Node::PosPart(a)),
        }
    }

    pub(super) fn fmod(&mut self, a: Id, b: Id) -> Id {
        match (self.value(a), self.value(b)) {
            (Some(x), Some(y)) => self.konst(libm::fmod(x, y)),
            _ => self.intern(Node::Fmod(a, b)),
        }
    }

    pub(super) fn select(&mut self, cmp: Cmp, a: Id, b: Id, then: Id, otherwise: Id) -> Id {
        if then == otherwise {
            return then;
        }
        match (self.value(a), self.value(b)) {
            (Some(x), Some(y)) => {
                if cmp.holds(x, y) {
                    then
                } else {
                    otherwise
                }
            }
            _ => self.intern(Node::Select(cmp, a, b, then, otherwise)),
        }
    }

    pub(super) fn if_tool(&mut self, tool: usize, x: Id) -> Id {
        if self.is(x, 0.0) {
            return x;
        }
        self.intern(Node::IfTool(u32::try_from(tool).unwrap_or(u32::MAX), x))
    }

    /// `Σ terms` left to right, skipping nothing (zeros fold away in `add`).
    pub(super) fn sum(&mut self, terms: impl IntoIterator<Item = Id>) -> Id {
        let mut acc: Option<Id> = None;
        for t in terms {
            acc = Some(match acc {
                None => t,
                Some(a) => self.add(a, t),
            });
        }
        acc.unwrap_or_else(|| self.konst(0.0))
    }

    /// Which nodes the effects need, directly or through operands.
    pub(super) fn live(&self) -> Vec<bool> {
        let mut live = vec![false; self.nodes.len()];
        for e in &self.effects {
            let roots = match *e {
                Effect::Store(_, _, v) | Effect::AddTo(_, _, v) | Effect::Eval(v) => {
                    [Some(v), None, None]
                }
                Effect::Pair(_, _, c, a, b) => [Some(c), Some(a), Some(b)],
            };
            for v in roots.into_iter().flatten() {
                if let Some(l) = live.get_mut(v.index()) {
                    *l = true;
                }
            }
        }
        // Operands precede their users, so one backward sweep reaches everything.
        for i in (0..self.nodes.len()).rev() {
            if !live.get(i).copied().unwrap_or(false) {
                continue;
            }
            for op in operands(self.nodes.get(i).copied().unwrap_or(Node::Const(0))) {
                if let Some(l) = live.get_mut(op.index()) {
                    *l = true;
                }
            }
        }
        live
    }
}

/// The operands of a node.
pub(super) fn operands(node: Node) -> impl Iterator<Item = Id> {
    let list: [Option<Id>; 4] = match node {
        Node::Const(_) | Node::Load(..) => [None; 4],
        Node::Neg(a)
        | Node::Floor(a)
        | Node::Sin(a)
        | Node::Cos(a)
        | Node::PosPart(a)
        | Node::IfTool(_, a) => [Some(a), None, None, None],
        Node::Add(a, b)
        | Node::Sub(a, b)
        | Node::Mul(a, b)
        | Node::Div(a, b)
        | Node::Fmod(a, b) => [Some(a), Some(b), None, None],
        Node::Select(_, a, b, t, e) => [Some(a), Some(b), Some(t), Some(e)],
    };
    list.into_iter().flatten()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folds_exact_identities_and_shares_nodes() {
        let mut g = Graph::default();
        let x = g.load(Src::Q, 0);
        let one = g.konst(1.0);
        let zero = g.konst(0.0);
        assert_eq!(g.mul(x, one), x);
        assert_eq!(g.add(zero, x), x);
        assert_eq!(g.mul(x, zero), zero);
        let m = g.konst(-1.0);
        let nx = g.mul(m, x);
        assert_eq!(g.neg(nx), x);
        let y = g.load(Src::Q, 1);
        assert_eq!(g.mul(x, y), g.mul(y, x));
        assert_ne!(g.sub(x, y), g.sub(y, x));
        let two = g.konst(2.0);
        let three = g.konst(3.0);
        let six = g.mul(two, three);
        assert_eq!(g.value(six), Some(6.0));
        let half = g.konst(0.5);
        let s = g.sin(half);
        assert_eq!(g.value(s), Some(libm::sin(0.5)));
    }

    #[test]
    fn only_needed_nodes_are_live() {
        let mut g = Graph::default();
        let x = g.load(Src::Q, 0);
        let y = g.load(Src::Q, 1);
        let unused = g.sin(y);
        let c = g.cos(x);
        g.store(Dst::Out, 0, c);
        let live = g.live();
        assert!(live[x.index()] && live[c.index()]);
        assert!(!live[y.index()] && !live[unused.index()]);
    }

    #[test]
    fn constant_selects_pick_a_branch() {
        let mut g = Graph::default();
        let (a, b) = (g.konst(0.3), g.konst(0.2));
        let x = g.load(Src::Q, 0);
        let zero = g.konst(0.0);
        assert_eq!(g.select(Cmp::Gt, a, b, x, zero), x);
        assert_eq!(g.select(Cmp::Gt, b, a, x, zero), zero);
        assert_eq!(g.select(Cmp::Ge, a, a, x, zero), x);
    }
}
