//! Resolution of the machine's structure: default units, axes, inputs, chains and tools.
//!
//! Produces the structural half of the IR (everything but the error models) and the name tables
//! the error-model checker resolves against. Every problem becomes a located diagnostic; the
//! walk goes on after an error so that one run reports all of them.

use std::collections::HashMap;

use crate::diagnostic::{suggest, Diagnostic, Span};
use crate::ir;
use crate::syntax::ast::{self, Expr, ExprKind, Name};
use crate::units::{Dim, Unit};

/// Collected diagnostics of one compilation.
#[derive(Default)]
pub(crate) struct Sink {
    pub diagnostics: Vec<Diagnostic>,
}

impl Sink {
    pub fn push(&mut self, d: Diagnostic) {
        self.diagnostics.push(d);
    }
    pub(crate) fn has_errors(&self) -> bool {
        self.diagnostics.iter().any(Diagnostic::is_error)
    }
}

/// The resolved structure of a machine, with the spans later stages cite.
pub(crate) struct Structure {
    pub name: String,
    pub task: ir::Task,
    /// The unit direction gravity acts in, base axes (`gravity along …`; −z by default).
    pub gravity: [f64; 3],
    pub units: ir::DisplayUnits,
    pub axes: Vec<ir::Axis>,
    pub axis_spans: Vec<Span>,
    /// Which chain and position each axis sits at, if any.
    pub axis_frame: Vec<Option<ir::FrameRef>>,
    pub inputs: Vec<ir::Input>,
    pub input_spans: Vec<Span>,
    /// Declared input range in SI, needed when an input is the variable of a ranged family.
    pub input_ranges: Vec<Option<[f64; 2]>>,
    pub tool_chain: Vec<ir::Element>,
    pub workpiece_chain: Vec<ir::Element>,
    pub tools: Vec<ir::Tool>,
    pub tool_spans: Vec<Span>,
    pub workpiece: ir::Shape,
    /// Axes and inputs whose declaration was wrong (and reported): later uses stay silent
    /// rather than cascade into "unknown name".
    pub broken: Vec<String>,
}

impl Structure {
    pub(crate) fn axis_index(&self, name: &str) -> Option<usize> {
        self.axes.iter().position(|a| a.name == name)
    }
    pub(crate) fn input_index(&self, name: &str) -> Option<usize> {
        self.inputs.iter().position(|i| i.name == name)
    }
    pub(crate) fn tool_index(&self, name: &str) -> Option<usize> {
        self.tools.iter().position(|t| t.name == name)
    }
}

/// Unit defaults for each kind of quantity, before the user's `units` block.
const DEFAULT_UNITS: [(&str, &str); 7] = [
    ("length", "mm"),
    ("angle", "deg"),
    ("error", "um"),
    ("tilt", "urad"),
    ("time", "s"),
    ("temperature", "degC"),
    ("force", "N"),
];

fn expected_dim(kind: &str) -> Option<Dim> {
    Some(match kind {
        "length" | "error" => Dim::LENGTH,
        "angle" | "tilt" => Dim::ANGLE,
        "time" => Dim::TIME,
        "temperature" => Dim::TEMPERATURE,
        "force" => Dim::FORCE,
        _ => return None,
    })
}

/// Parses unit text from the source, reporting an unknown unit at its span.
pub(crate) fn parse_unit(name: &Name, sink: &mut Sink) -> Option<Unit> {
    match Unit::parse(&name.node) {
        Ok(u) => Some(u),
        Err(e) => {
            let label = match e {
                crate::units::UnitError::ExponentRange { .. } => "exponent out of range",
                _ => "not a unit kin knows",
            };
            let mut d = Diagnostic::error("E0103", format!("{e} in `{}`", name.node), name.span)
                .with_label(label);
            if matches!(e, crate::units::UnitError::ExponentRange { .. }) {
                d = d.with_help("powers of units run from -127 to 127");
            } else if let Some(s) = suggest(&name.node, Unit::ATOM_NAMES) {
                d = d.with_help(format!("did you mean `{s}`?"));
            } else {
                d = d.with_note(format!("known units: {}", Unit::ATOM_NAMES.join(" ")));
            }
            sink.push(d);
            None
        }
    }
}

/// A constant quantity: its value in SI and its dimension. `bare` marks a number written
/// without a unit, which takes the default unit of the place it stands in.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Constant {
    pub value: f64,
    pub dim: Dim,
    pub bare: bool,
}

/// Folds a constant expression (numbers with units and arithmetic). `absolute` says whether a
/// lone `degC` is an absolute temperature (with the 273.15 offset) or a difference.
pub(crate) fn constant(expr: &Expr, absolute: bool, sink: &mut Sink) -> Option<Constant> {
    let c = constant_inner(expr, absolute, sink)?;
    if !c.value.is_finite() {
        sink.push(
            Diagnostic::error(
                "E0003",
                "this constant is too large to represent",
                expr.span,
            )
            .with_label("not a finite number")
            .with_help("numbers must stay within double precision (about 1e308)"),
        );
        return None;
    }
    Some(c)
}

fn constant_inner(expr: &Expr, absolute: bool, sink: &mut Sink) -> Option<Constant> {
    match &expr.kind {
        ExprKind::Quantity { value, unit } => match unit {
            None => Some(Constant {
                value: *value,
                dim: Dim::DIMENSIONLESS,
                bare: true,
            }),
            Some(u) => {
                let unit = parse_unit(u, sink)?;
                let unit = if absolute { unit } else { unit.as_difference() };
                Some(Constant {
                    value: unit.to_si(*value),
                    dim: unit.dim,
                    bare: false,
                })
            }
        },
        ExprKind::Neg(inner) => {
            let c = constant(inner, absolute, sink)?;
            Some(Constant {
                value: -c.value,
                ..c
            })
        }
        ExprKind::Binary(op, a, b) => {
            let x = constant(a, absolute, sink)?;
            let y = constant(b, absolute, sink)?;
            match op {
                ast::BinOp::Add | ast::BinOp::Sub => {
                    if x.dim != y.dim && !(x.bare || y.bare) {
                        sink.push(dimension_mismatch(expr.span, a.span, x.dim, b.span, y.dim));
                        return None;
                    }
                    let dim = if x.bare { y.dim } else { x.dim };
                    let value = if *op == ast::BinOp::Add {
                        x.value + y.value
                    } else {
                        x.value - y.value
                    };
                    Some(Constant {
                        value,
                        dim,
                        bare: x.bare && y.bare,
                    })
                }
                ast::BinOp::Mul => Some(Constant {
                    value: x.value * y.value,
                    dim: x.dim * y.dim,
                    bare: x.bare && y.bare,
                }),
                ast::BinOp::Div => {
                    if y.value == 0.0 {
                        sink.push(
                            Diagnostic::error("E0003", "division by zero", b.span)
                                .with_label("this is zero"),
                        );
                        return None;
                    }
                    Some(Constant {
                        value: x.value / y.value,
                        dim: x.dim / y.dim,
                        bare: x.bare && y.bare,
                    })
                }
            }
        }
        _ => {
            sink.push(
                Diagnostic::error(
                    "E0203",
                    "expected a constant quantity such as `600 mm`",
                    expr.span,
                )
                .with_label("not a constant")
                .with_note(
                    "ranges, offsets and options take numbers with units, not machine state",
                ),
            );
            None
        }
    }
}

pub(crate) fn dimension_mismatch(op: Span, a: Span, da: Dim, b: Span, db: Dim) -> Diagnostic {
    Diagnostic::error(
        "E0201",
        format!(
            "cannot add or subtract {} and {}",
            da.describe(),
            db.describe()
        ),
        op,
    )
    .with_label("mismatched dimensions")
    .with_secondary(a, format!("this is {}", da.describe()))
    .with_secondary(b, format!("this is {}", db.describe()))
}

/// A constant of an expected dimension, in SI. A bare number takes `default`.
pub(crate) fn quantity_of(
    expr: &Expr,
    dim: Dim,
    default: &Unit,
    absolute: bool,
    what: &str,
    sink: &mut Sink,
) -> Option<f64> {
    let c = constant(expr, absolute, sink)?;
    if c.bare {
        let unit = if absolute {
            default.clone()
        } else {
            default.as_difference()
        };
        return Some(unit.to_si(c.value));
    }
    if c.dim != dim {
        sink.push(
            Diagnostic::error(
                "E0203",
                format!(
                    "{what} must be {}, but this is {}",
                    dim.describe(),
                    c.dim.describe()
                ),
                expr.span,
            )
            .with_label(format!("expected {}", dim.describe()))
            .with_help(format!(
                "write it in {} units, e.g. `{}`",
                dim.describe(),
                default.name
            )),
        );
        return None;
    }
    Some(c.value)
}

/// The largest length a machine's geometry (an offset, an axis range) may state: 10 km, beyond
/// any machine. A larger one is a typo (`1e100 mm`) and, left alone, swamps every other column
/// of the identifiability analysis and the fit, whose complaints then land on innocent terms.
const MAX_GEOMETRY_LENGTH: f64 = 1e4;
/// The same for angles (rotations of frames, revolute ranges): 10⁶ rad, some 160 000 turns.
const MAX_GEOMETRY_ANGLE: f64 = 1e6;

/// `value` (SI) when it is within the bound of its dimension, else an `E0003` at `span`.
fn within_machine(value: f64, dim: Dim, span: Span, what: &str, sink: &mut Sink) -> Option<f64> {
    let (bound, text, unit) = if dim == Dim::LENGTH {
        (MAX_GEOMETRY_LENGTH, "10 km", "m")
    } else if dim == Dim::ANGLE {
        (MAX_GEOMETRY_ANGLE, "10⁶ rad", "rad")
    } else {
        return Some(value);
    };
    if value.abs() <= bound {
        return Some(value);
    }
    sink.push(
        Diagnostic::error(
            "E0003",
            format!("{what}: {value:e} {unit} is beyond any machine"),
            span,
        )
        .with_label(format!("larger than {text}"))
        .with_help(format!(
            "a machine's offsets and ranges are at most {text}; check the number and its unit"
        )),
    );
    None
}

pub(crate) fn resolve(machine: &ast::Machine, sink: &mut Sink) -> Structure {
    let units = resolve_units(machine, sink);
    let task = resolve_task(machine, sink);
    let gravity = resolve_gravity(machine, sink);
    let mut st = Structure {
        name: machine.name.node.clone(),
        task,
        gravity,
        units,
        axes: Vec::new(),
        axis_spans: Vec::new(),
        axis_frame: Vec::new(),
        inputs: Vec::new(),
        input_spans: Vec::new(),
        input_ranges: Vec::new(),
        tool_chain: Vec::new(),
        workpiece_chain: Vec::new(),
        tools: Vec::new(),
        tool_spans: Vec::new(),
        workpiece: ir::Shape::default(),
        broken: Vec::new(),
    };
    // Names of axes, inputs and tools share one namespace: an error target or a variable must
    // mean exactly one thing.
    let mut names: HashMap<String, Span> = HashMap::new();
    let mut claim = |n: &Name, what: &str, sink: &mut Sink| -> bool {
        if let Some(first) = names.get(&n.node) {
            sink.push(
                Diagnostic::error("E0102", format!("`{}` is defined twice", n.node), n.span)
                    .with_label(format!("second definition, as {what}"))
                    .with_secondary(*first, "first defined here")
                    .with_help("axes, inputs and tools share one namespace; rename one of them"),
            );
            return false;
        }
        if matches!(n.node.as_str(), "time" | "tool" | "workpiece") {
            sink.push(
                Diagnostic::error("E0102", format!("`{}` is a reserved name", n.node), n.span)
                    .with_label("reserved"),
            );
            return false;
        }
        names.insert(n.node.clone(), n.span);
        true
    };
    for item in &machine.items {
        match item {
            ast::Item::Axis(a) if claim(&a.name, "an axis", sink) => {
                if let Some(axis) = resolve_axis(a, &st.units, sink) {
                    st.axes.push(axis);
                    st.axis_spans.push(a.name.span);
                    st.axis_frame.push(None);
                } else {
                    st.broken.push(a.name.node.clone());
                }
            }
            ast::Item::Input(i) if claim(&i.name, "an input", sink) => {
                if let Some((input, range)) = resolve_input(i, &st.units, sink) {
                    st.inputs.push(input);
                    st.input_spans.push(i.name.span);
                    st.input_ranges.push(range);
                } else {
                    st.broken.push(i.name.node.clone());
                }
            }
            ast::Item::Chain(c) => {
                for ci in &c.items {
                    if let ast::ChainItem::Tool { name, .. } = ci {
                        claim(name, "a tool", sink);
                    }
                }
            }
            _ => {}
        }
    }
    resolve_chains(machine, &mut st, sink);
    st
}

fn resolve_units(machine: &ast::Machine, sink: &mut Sink) -> ir::DisplayUnits {
    let mut chosen: HashMap<&str, (Unit, Span)> = HashMap::new();
    for item in &machine.items {
        let ast::Item::Units(decl) = item else {
            continue;
        };
        for b in &decl.bindings {
            let kind = b.quantity.node.as_str();
            let Some(dim) = expected_dim(kind) else {
                let kinds = DEFAULT_UNITS.map(|(k, _)| k);
                let mut d = Diagnostic::error(
                    "E0103",
                    format!("unknown quantity `{kind}` in `units`"),
                    b.quantity.span,
                )
                .with_label("not a quantity kind")
                .with_note(format!("the kinds are: {}", kinds.join(", ")));
                if let Some(s) = suggest(kind, kinds) {
                    d = d.with_help(format!("did you mean `{s}`?"));
                }
                sink.push(d);
                continue;
            };
            let Some(unit) = parse_unit(&b.unit, sink) else {
                continue;
            };
            if unit.dim != dim {
                sink.push(
                    Diagnostic::error(
                        "E0203",
                        format!(
                            "`{}` is {}, but {kind} is {}",
                            unit.name,
                            unit.dim.describe(),
                            dim.describe()
                        ),
                        b.unit.span,
                    )
                    .with_label(format!("expected a unit of {}", dim.describe())),
                );
                continue;
            }
            if let Some((_, first)) = chosen.get(kind) {
                sink.push(
                    Diagnostic::error(
                        "E0102",
                        format!("the unit of `{kind}` is given twice"),
                        b.quantity.span,
                    )
                    .with_label("second definition")
                    .with_secondary(*first, "first defined here"),
                );
                continue;
            }
            chosen.insert(kind, (unit, b.quantity.span));
        }
    }
    let pick = |kind: &str| -> Unit {
        chosen.get(kind).map(|(u, _)| u.clone()).unwrap_or_else(|| {
            let text = DEFAULT_UNITS
                .iter()
                .find(|(k, _)| *k == kind)
                .map(|(_, u)| *u)
                .unwrap_or("1");
            Unit::parse(text).unwrap_or_else(|_| Unit::dimensionless())
        })
    };
    ir::DisplayUnits {
        length: pick("length"),
        angle: pick("angle"),
        error: pick("error"),
        tilt: pick("tilt"),
        time: pick("time"),
        temperature: pick("temperature"),
        force: pick("force"),
    }
}

fn resolve_task(machine: &ast::Machine, sink: &mut Sink) -> ir::Task {
    let mut task: Option<(ir::Task, Span)> = None;
    for item in &machine.items {
        let ast::Item::Task(t) = item else { continue };
        if let Some((_, first)) = task {
            sink.push(
                Diagnostic::error("E0102", "the task is given twice", t.span)
                    .with_label("second definition")
                    .with_secondary(first, "first defined here"),
            );
            continue;
        }
        let kind = match t.node {
            ast::TaskKind::Measure => ir::Task::Measure,
            ast::TaskKind::Position => ir::Task::Position,
        };
        task = Some((kind, t.span));
    }
    match task {
        Some((t, _)) => t,
        None => {
            sink.push(
                Diagnostic::error("E0110", format!("machine `{}` does not say its task", machine.name.node), machine.name.span)
                    .with_label("no `task` declaration")
                    .with_note("the task fixes the sign of every error: a measuring machine reports indicated − true, a positioning machine actual − nominal (thesis eq. 2.31/2.34)")
                    .with_help("add `task measure` (CMM) or `task position` (machine tool, robot)"),
            );
            ir::Task::Position
        }
    }
}

/// `gravity along …`, at most once; −z of the base when not given (a machine standing on the
/// floor with z up, as most are).
fn resolve_gravity(machine: &ast::Machine, sink: &mut Sink) -> [f64; 3] {
    let mut found: Option<([f64; 3], Span)> = None;
    for item in &machine.items {
        let ast::Item::Gravity(g) = item else {
            continue;
        };
        if let Some((_, first)) = found {
            sink.push(
                Diagnostic::error("E0102", "gravity is given twice", g.span)
                    .with_label("second definition")
                    .with_secondary(first, "first defined here"),
            );
            continue;
        }
        let zero = |span: Span| {
            Diagnostic::error("E0405", "gravity has a zero direction", span)
                .with_label("this vector has no length")
                .with_help("give the direction gravity acts in, e.g. `gravity along -z` or `gravity along (0, 0.5, -0.866)`")
        };
        if let Some(d) = direction(&g.node, zero, sink) {
            found = Some((d, g.span));
        }
    }
    found.map_or(ir::GRAVITY, |(d, _)| d)
}

/// A declared direction as a unit vector; `zero` says what a vector without length is.
fn direction(
    d: &ast::Direction,
    zero: impl FnOnce(Span) -> Diagnostic,
    sink: &mut Sink,
) -> Option<[f64; 3]> {
    Some(match d {
        ast::Direction::Coordinate { negative, index } => {
            let mut d = [0.0; 3];
            if let Some(slot) = d.get_mut(*index) {
                *slot = if *negative { -1.0 } else { 1.0 };
            }
            d
        }
        ast::Direction::Vector(v) => {
            let mut d = [0.0; 3];
            for (slot, e) in d.iter_mut().zip(&v.elems) {
                let c = constant(e, false, sink)?;
                if !c.dim.is_dimensionless() {
                    sink.push(
                        Diagnostic::error("E0203", "a direction is a dimensionless vector", e.span)
                            .with_label(format!("this is {}", c.dim.describe())),
                    );
                    return None;
                }
                *slot = c.value;
            }
            let norm = d.iter().map(|x| x * x).sum::<f64>().sqrt();
            if !(norm > 1e-12) || !norm.is_finite() {
                sink.push(zero(v.span));
                return None;
            }
            d.map(|x| x / norm)
        }
    })
}

fn resolve_axis(a: &ast::AxisDecl, units: &ir::DisplayUnits, sink: &mut Sink) -> Option<ir::Axis> {
    let kind = match a.kind.node {
        ast::JointKind::Prismatic => ir::JointKind::Prismatic,
        ast::JointKind::Revolute => ir::JointKind::Revolute,
    };
    let zero = |span: Span| {
        Diagnostic::error(
            "E0405",
            format!("axis `{}` has a zero direction", a.name.node),
            span,
        )
        .with_label("this vector has no length")
        .with_help("give the direction of motion, e.g. `along (0, 0.6, 0.8)` or `along -x`")
    };
    let direction = direction(&a.direction.node, zero, sink)?;
    let (dim, default) = match kind {
        ir::JointKind::Prismatic => (Dim::LENGTH, &units.length),
        ir::JointKind::Revolute => (Dim::ANGLE, &units.angle),
    };
    let (range, continuous) = match &a.range {
        None => {
            if kind == ir::JointKind::Revolute {
                sink.push(
                    Diagnostic::error(
                        "E0304",
                        format!("revolute axis `{}` has no range", a.name.node),
                        a.name.span,
                    )
                    .with_label("needs `range LO .. HI` or `continuous`")
                    .with_help(
                        "add `continuous` for a full-turn axis, or e.g. `range -90 deg .. 90 deg`",
                    ),
                );
            } else {
                sink.push(
                    Diagnostic::error("E0304", format!("prismatic axis `{}` has no range", a.name.node), a.name.span)
                        .with_label("needs `range LO .. HI`")
                        .with_note("error models are defined over the axis range (normalised variables, knots, straightness)")
                        .with_help("add e.g. `range 0 mm .. 600 mm`"),
                );
            }
            return None;
        }
        Some(r) => match &r.node {
            ast::AxisRange::Continuous => {
                if kind == ir::JointKind::Prismatic {
                    sink.push(
                        Diagnostic::error("E0304", "a prismatic axis cannot be continuous", r.span)
                            .with_label("only a revolute axis turns without end")
                            .with_help("give a range, e.g. `range 0 mm .. 600 mm`"),
                    );
                    return None;
                }
                ([0.0, std::f64::consts::TAU], true)
            }
            ast::AxisRange::Interval(lo, hi) => {
                let what = format!(
                    "the range of {} axis `{}`",
                    if kind == ir::JointKind::Prismatic {
                        "prismatic"
                    } else {
                        "revolute"
                    },
                    a.name.node
                );
                let l = quantity_of(lo, dim, default, false, &what, sink)
                    .and_then(|v| within_machine(v, dim, lo.span, &what, sink));
                let h = quantity_of(hi, dim, default, false, &what, sink)
                    .and_then(|v| within_machine(v, dim, hi.span, &what, sink));
                let (l, h) = (l?, h?);
                if !(l < h) {
                    sink.push(
                        Diagnostic::error(
                            "E0304",
                            format!("the range of `{}` is empty or inverted", a.name.node),
                            r.span,
                        )
                        .with_label("the lower end must be below the upper end"),
                    );
                    return None;
                }
                ([l, h], false)
            }
        },
    };
    Some(ir::Axis {
        name: a.name.node.clone(),
        kind,
        direction,
        range,
        continuous,
    })
}

/// The default unit of a heat-source input kind; the names are fixed here, so parsing cannot
/// fail, and the SI unit of the dimension stands in should it ever.
fn heat_source_unit(text: &str) -> Unit {
    Unit::parse(text).unwrap_or_else(|_| {
        Unit::si(match text {
            "rpm" => Dim::SPEED,
            "W" => Dim::POWER,
            _ => Dim::VELOCITY,
        })
    })
}

fn resolve_input(
    i: &ast::InputDecl,
    units: &ir::DisplayUnits,
    sink: &mut Sink,
) -> Option<(ir::Input, Option<[f64; 2]>)> {
    let kind = i.dimension.node.as_str();
    let (dim, default) = match kind {
        "temperature" => (Dim::TEMPERATURE, units.temperature.clone()),
        "force" => (Dim::FORCE, units.force.clone()),
        "length" => (Dim::LENGTH, units.length.clone()),
        "angle" => (Dim::ANGLE, units.angle.clone()),
        "time" => (Dim::TIME, units.time.clone()),
        "dimensionless" => (Dim::DIMENSIONLESS, Unit::dimensionless()),
        // Heat sources: what drives a machine's thermal state besides the temperatures. Their
        // default units are the ones a controller reports (a spindle's rpm, a feed in mm/min).
        "speed" => (Dim::SPEED, heat_source_unit("rpm")),
        "velocity" => (Dim::VELOCITY, heat_source_unit("mm/min")),
        "power" => (Dim::POWER, heat_source_unit("W")),
        _ => {
            let kinds = [
                "temperature",
                "force",
                "length",
                "angle",
                "time",
                "dimensionless",
                "speed",
                "velocity",
                "power",
            ];
            let mut d = Diagnostic::error(
                "E0101",
                format!("unknown input kind `{kind}`"),
                i.dimension.span,
            )
            .with_label("not a kind of input")
            .with_note(format!("input kinds: {}", kinds.join(", ")));
            if let Some(s) = suggest(kind, kinds) {
                d = d.with_help(format!("did you mean `{s}`?"));
            }
            sink.push(d);
            return None;
        }
    };
    let mut absolute = None;
    let mut unit = default;
    let mut range_expr = None;
    for opt in &i.options {
        match opt {
            ast::InputOption::Flag(f) => absolute = Some((f.node == "absolute", f.span)),
            ast::InputOption::Unit(u) => {
                let parsed = parse_unit(u, sink)?;
                if parsed.dim != dim {
                    sink.push(
                        Diagnostic::error(
                            "E0203",
                            format!(
                                "input `{}` is {}, but `{}` is {}",
                                i.name.node,
                                dim.describe(),
                                parsed.name,
                                parsed.dim.describe()
                            ),
                            u.span,
                        )
                        .with_label(format!("expected a unit of {}", dim.describe())),
                    );
                    return None;
                }
                unit = parsed;
            }
            ast::InputOption::Range(lo, hi, span) => range_expr = Some((lo, hi, *span)),
        }
    }
    let absolute = match (dim == Dim::TEMPERATURE, absolute) {
        (true, Some((a, _))) => a,
        (true, None) => {
            sink.push(
                Diagnostic::error("E0111", format!("temperature input `{}` must say `rise` or `absolute`", i.name.node), i.name.span)
                    .with_label("absolute temperature or temperature rise?")
                    .with_note("an absolute temperature in degC converts with the 273.15 K offset, a rise does not")
                    .with_help(format!("write `input {} : temperature absolute` or `… temperature rise`", i.name.node)),
            );
            return None;
        }
        (false, Some((_, span))) => {
            sink.push(
                Diagnostic::error(
                    "E0105",
                    "`rise` and `absolute` apply to temperature inputs only",
                    span,
                )
                .with_label("not a temperature"),
            );
            return None;
        }
        (false, None) => false,
    };
    let unit = if absolute {
        unit.as_absolute()
    } else {
        unit.as_difference()
    };
    let range = match range_expr {
        None => None,
        Some((lo, hi, span)) => {
            let what = format!("the range of input `{}`", i.name.node);
            let l = quantity_of(lo, dim, &unit, absolute, &what, sink)?;
            let h = quantity_of(hi, dim, &unit, absolute, &what, sink)?;
            if !(l < h) {
                sink.push(
                    Diagnostic::error(
                        "E0304",
                        format!("the range of `{}` is empty or inverted", i.name.node),
                        span,
                    )
                    .with_label("the lower end must be below the upper end"),
                );
                return None;
            }
            Some([l, h])
        }
    };
    Some((
        ir::Input {
            name: i.name.node.clone(),
            unit,
            absolute,
            range,
        },
        range,
    ))
}

fn resolve_chains(machine: &ast::Machine, st: &mut Structure, sink: &mut Sink) {
    let mut seen_chain: [Option<Span>; 2] = [None, None];
    let mut axis_use: Vec<Option<Span>> = vec![None; st.axes.len()];
    let mut workpiece_seen: Option<Span> = None;
    for item in &machine.items {
        let ast::Item::Chain(chain) = item else {
            continue;
        };
        let slot = match chain.kind.node {
            ast::ChainKind::Tool => 0,
            ast::ChainKind::Workpiece => 1,
        };
        if let Some(Some(first)) = seen_chain.get(slot) {
            sink.push(
                Diagnostic::error("E0102", "this chain is declared twice", chain.kind.span)
                    .with_label("second declaration")
                    .with_secondary(*first, "first declared here")
                    .with_help("list all elements of a chain in one block, from the base outward"),
            );
        }
        // A second block of the same chain is reported, but its items are still read: the
        // user means them, and skipping them would report every axis in it as unplaced.
        if let Some(s) = seen_chain.get_mut(slot) {
            s.get_or_insert(chain.kind.span);
        }
        for ci in &chain.items {
            match ci {
                ast::ChainItem::Element {
                    axis,
                    frame,
                    placement,
                    span,
                } => {
                    let Some(index) = st.axis_index(&axis.node) else {
                        if !st.broken.contains(&axis.node) {
                            sink.push(not_an_axis(axis, st));
                        }
                        continue;
                    };
                    if let Some(first) = axis_use.get(index).copied().flatten() {
                        sink.push(
                            Diagnostic::error(
                                "E0402",
                                format!("axis `{}` is used twice", axis.node),
                                axis.span,
                            )
                            .with_label("second use")
                            .with_secondary(first, "first used here")
                            .with_note(
                                "each axis is one joint: it sits in exactly one chain, once",
                            ),
                        );
                        continue;
                    }
                    if let Some(u) = axis_use.get_mut(index) {
                        *u = Some(*span);
                    }
                    let shape = resolve_placement(placement, &st.units, sink);
                    let element = ir::Element {
                        axis: index,
                        frame: match frame.node {
                            ast::FrameKind::Moving => ir::FrameKind::Moving,
                            ast::FrameKind::Fixed => ir::FrameKind::Fixed,
                        },
                        shape,
                    };
                    let list = if slot == 0 {
                        &mut st.tool_chain
                    } else {
                        &mut st.workpiece_chain
                    };
                    let frame_ref = if slot == 0 {
                        ir::FrameRef::Tool(list.len())
                    } else {
                        ir::FrameRef::Workpiece(list.len())
                    };
                    list.push(element);
                    if let Some(f) = st.axis_frame.get_mut(index) {
                        *f = Some(frame_ref);
                    }
                }
                ast::ChainItem::Tool {
                    name,
                    placement,
                    span,
                } => {
                    if slot == 1 {
                        sink.push(
                            Diagnostic::error("E0404", "a tool belongs in the tool chain", *span)
                                .with_label("tool in the workpiece chain")
                                .with_help("move it into `tool chain { … }`"),
                        );
                        continue;
                    }
                    let offset = resolve_placement(placement, &st.units, sink);
                    st.tools.push(ir::Tool {
                        name: name.node.clone(),
                        offset,
                    });
                    st.tool_spans.push(name.span);
                }
                ast::ChainItem::Workpiece { placement, span } => {
                    if slot == 0 {
                        sink.push(
                            Diagnostic::error(
                                "E0404",
                                "the workpiece belongs in the workpiece chain",
                                *span,
                            )
                            .with_label("workpiece in the tool chain")
                            .with_help("move it into `workpiece chain { … }`"),
                        );
                        continue;
                    }
                    if let Some(first) = workpiece_seen {
                        sink.push(
                            Diagnostic::error("E0404", "the workpiece is declared twice", *span)
                                .with_label("second workpiece")
                                .with_secondary(first, "first declared here")
                                .with_note("a machine has one workpiece reference frame"),
                        );
                        continue;
                    }
                    workpiece_seen = Some(*span);
                    st.workpiece = resolve_placement(placement, &st.units, sink);
                }
            }
        }
    }
    for (index, used) in axis_use.iter().enumerate() {
        if used.is_none() {
            if let (Some(axis), Some(span)) = (st.axes.get(index), st.axis_spans.get(index)) {
                sink.push(
                    Diagnostic::error(
                        "E0401",
                        format!("axis `{}` is used in no chain", axis.name),
                        *span,
                    )
                    .with_label("declared here, but never placed")
                    .with_help(format!(
                        "add `{} moving` to the tool chain or the workpiece chain",
                        axis.name
                    )),
                );
            }
        }
    }
    if st.tools.is_empty() {
        let span = seen_chain[0].unwrap_or(machine.name.span);
        sink.push(
            Diagnostic::error("E0112", "the machine declares no tool", span)
                .with_label("no `tool` in the tool chain")
                .with_note("the error of the tool frame relative to the workpiece is what every observation measures")
                .with_help("add e.g. `tool probe at (0, 0, -150) mm` at the end of the tool chain"),
        );
    }
}

fn not_an_axis(name: &Name, st: &Structure) -> Diagnostic {
    let mut d = Diagnostic::error(
        "E0403",
        format!("chain element `{}` is not an axis", name.node),
        name.span,
    );
    if st.input_index(&name.node).is_some() {
        d = d
            .with_label("this is an input")
            .with_note("a chain element is a joint: a declared axis");
    } else {
        d = d.with_label("unknown axis");
        if let Some(s) = suggest(&name.node, st.axes.iter().map(|a| a.name.as_str())) {
            d = d.with_help(format!("did you mean `{s}`?"));
        } else {
            d = d.with_help(format!(
                "declare it first: `axis {} prismatic along x range 0 mm .. 500 mm`",
                name.node
            ));
        }
    }
    d
}

fn resolve_placement(p: &ast::Placement, units: &ir::DisplayUnits, sink: &mut Sink) -> ir::Shape {
    let mut shape = ir::Shape::default();
    if let Some(v) = &p.at {
        shape.translation = vector_of(v, Dim::LENGTH, &units.length, "an offset", sink);
    }
    if let Some(v) = &p.rot {
        shape.rotation = vector_of(v, Dim::ANGLE, &units.angle, "a rotation", sink);
    }
    shape
}

/// A vector of three quantities: a trailing unit applies to bare numbers; otherwise each number
/// carries its own unit or takes the default.
fn vector_of(v: &ast::Vector, dim: Dim, default: &Unit, what: &str, sink: &mut Sink) -> [f64; 3] {
    let unit = match &v.unit {
        Some(u) => match parse_unit(u, sink) {
            Some(unit) if unit.dim == dim => unit,
            Some(unit) => {
                sink.push(
                    Diagnostic::error(
                        "E0203",
                        format!(
                            "{what} must be {}, but `{}` is {}",
                            dim.describe(),
                            unit.name,
                            unit.dim.describe()
                        ),
                        u.span,
                    )
                    .with_label(format!("expected a unit of {}", dim.describe())),
                );
                return [0.0; 3];
            }
            None => return [0.0; 3],
        },
        None => default.clone(),
    };
    let mut out = [0.0; 3];
    for (slot, e) in out.iter_mut().zip(&v.elems) {
        *slot = quantity_of(e, dim, &unit, false, what, sink)
            .and_then(|x| within_machine(x, dim, e.span, what, sink))
            .unwrap_or(0.0);
    }
    out
}
