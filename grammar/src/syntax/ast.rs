//! The typed syntax tree. It mirrors the grammar, keeps every source span, and decides nothing
//! about meaning: names are unresolved text and units are unparsed text.

use crate::diagnostic::Span;

#[derive(Debug, Clone, PartialEq)]
pub struct Spanned<T> {
    pub node: T,
    pub span: Span,
}

pub type Name = Spanned<String>;

#[derive(Debug, Clone, PartialEq)]
pub struct File {
    pub machine: Machine,
    pub params: Option<ParamsBlock>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Machine {
    pub name: Name,
    pub items: Vec<Item>,
    pub span: Span,
}

impl Machine {
    /// The byte offset of the closing brace of the last `errors` block: where a line that adds
    /// to the model goes (`kin diagnose`).
    pub fn errors_close(&self) -> Option<usize> {
        self.items
            .iter()
            .filter_map(|i| match i {
                Item::Errors(e) => e.span.end.checked_sub(1),
                _ => None,
            })
            .max()
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    Task(Spanned<TaskKind>),
    Units(UnitsDecl),
    /// `gravity along …`: the direction gravity acts in (the whole declaration's span).
    Gravity(Spanned<Direction>),
    Axis(Box<AxisDecl>),
    Input(InputDecl),
    Chain(ChainDecl),
    Errors(ErrorsDecl),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TaskKind {
    Measure,
    Position,
}

#[derive(Debug, Clone, PartialEq)]
pub struct UnitsDecl {
    pub bindings: Vec<UnitBinding>,
    pub span: Span,
}

/// `length mm`: the default unit of one quantity.
#[derive(Debug, Clone, PartialEq)]
pub struct UnitBinding {
    pub quantity: Name,
    pub unit: Name,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    Prismatic,
    Revolute,
}

#[derive(Debug, Clone, PartialEq)]
pub struct AxisDecl {
    pub name: Name,
    pub kind: Spanned<JointKind>,
    pub direction: Spanned<Direction>,
    pub range: Option<Spanned<AxisRange>>,
    pub span: Span,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Direction {
    /// `along -x`: sign and coordinate index (0 = x).
    Coordinate {
        negative: bool,
        index: usize,
    },
    Vector(Box<Vector>),
}

#[derive(Debug, Clone, PartialEq)]
pub enum AxisRange {
    Continuous,
    Interval(Expr, Expr),
}

#[derive(Debug, Clone, PartialEq)]
pub struct InputDecl {
    pub name: Name,
    /// `temperature`, `force`, …: checked by the resolver.
    pub dimension: Name,
    pub options: Vec<InputOption>,
    pub span: Span,
}

#[derive(Debug, Clone, PartialEq)]
pub enum InputOption {
    /// `rise` or `absolute`.
    Flag(Name),
    Range(Expr, Expr, Span),
    Unit(Name),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChainKind {
    Tool,
    Workpiece,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ChainDecl {
    pub kind: Spanned<ChainKind>,
    pub items: Vec<ChainItem>,
    pub span: Span,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    Moving,
    Fixed,
}

#[derive(Debug, Clone, PartialEq)]
pub enum ChainItem {
    Element {
        axis: Name,
        frame: Spanned<FrameKind>,
        placement: Placement,
        span: Span,
    },
    Tool {
        name: Name,
        placement: Placement,
        span: Span,
    },
    Workpiece {
        placement: Placement,
        span: Span,
    },
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct Placement {
    pub at: Option<Vector>,
    pub rot: Option<Vector>,
}

/// `(a, b, c) unit`: three expressions and an optional unit applying to all three.
#[derive(Debug, Clone, PartialEq)]
pub struct Vector {
    pub elems: [Expr; 3],
    pub unit: Option<Name>,
    pub span: Span,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ErrorsDecl {
    pub defs: Vec<ErrorDef>,
    pub span: Span,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ErrorDef {
    /// One or more (`X.tx, X.ry += …`): never empty. Every target takes the same terms with
    /// its own coefficients; the non-linear parameters and lags the value declares are one.
    pub targets: Vec<Target>,
    /// `+=` rather than `=`.
    pub add: bool,
    pub value: Expr,
    pub span: Span,
}

/// `X.tx`, `probe.rz`, or a one-word alias such as `EXX` or `xtx`.
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    pub frame: Name,
    pub component: Option<Name>,
    pub span: Span,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Expr {
    pub kind: ExprKind,
    pub span: Span,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
}

impl BinOp {
    pub fn symbol(self) -> &'static str {
        match self {
            BinOp::Add => "+",
            BinOp::Sub => "-",
            BinOp::Mul => "*",
            BinOp::Div => "/",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum ExprKind {
    /// A number with an optional unit: `600 mm`, `2`.
    Quantity {
        value: f64,
        unit: Option<Name>,
    },
    Const,
    Name(String),
    Neg(Box<Expr>),
    Binary(BinOp, Box<Expr>, Box<Expr>),
    Call {
        name: Name,
        args: Vec<Arg>,
    },
}

#[derive(Debug, Clone, PartialEq)]
pub enum Arg {
    Positional(Expr),
    Option(OptionArg),
}

/// `knots 5`, `tau fit 30 min`, `knots at (100, 200) mm`, `harmonics 2..4`.
#[derive(Debug, Clone, PartialEq)]
pub struct OptionArg {
    pub name: Name,
    pub fit: Option<Span>,
    pub value: OptionValue,
    pub span: Span,
}

#[derive(Debug, Clone, PartialEq)]
pub enum OptionValue {
    Expr(Expr),
    At {
        items: Vec<Expr>,
        unit: Option<Name>,
        span: Span,
    },
    IntRange {
        lo: i64,
        hi: i64,
        span: Span,
    },
    IntList {
        items: Vec<i64>,
        span: Span,
    },
}

impl OptionValue {
    pub fn span(&self) -> Span {
        match self {
            OptionValue::Expr(e) => e.span,
            OptionValue::At { span, .. }
            | OptionValue::IntRange { span, .. }
            | OptionValue::IntList { span, .. } => *span,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct ParamsBlock {
    pub defs: Vec<ParamDef>,
    pub span: Span,
}

/// `Y.ty[0] = 1.2 um`, `Y.ty = [1.2, -0.5] um`, `Z.tz.tau = 28 min`.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamDef {
    pub path: Vec<Name>,
    pub index: Option<Spanned<i64>>,
    /// The span of a `+=`, which parameter values do not take (reported by the binder).
    pub add: Option<Span>,
    pub value: ParamValue,
    pub span: Span,
}

#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    Scalar(Expr),
    List {
        values: Vec<f64>,
        unit: Option<Name>,
        span: Span,
    },
}
