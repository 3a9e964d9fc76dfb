//! Checking of the error models: targets, expressions, factor families and dimensions.
//!
//! An error model is an expression; it is expanded into a sum of terms, each a product of basis
//! factors (dimensionless families that bring coefficients β) and a known scalar (numbers with
//! units, machine state, lags). A fitted term's coefficients get the derived unit
//! `component unit / unit of the scalar`; a term without basis factors is a known, fixed error
//! and must have the component's own dimension.

use std::collections::HashMap;

use crate::basis::{self, Basis, Detrend, Wavelength};
use crate::diagnostic::{suggest, Diagnostic, Span};
use crate::ir::{self, Component, FrameRef, JointKind, NonLinear, Scalar, Var};
use crate::resolve::{constant, dimension_mismatch, parse_unit, quantity_of, Sink, Structure};
use crate::syntax::ast::{self, Arg, BinOp, Expr, ExprKind, OptionArg, OptionValue};
use crate::units::{Dim, Unit};

/// The checked error models and everything they introduced.
pub(crate) struct Models {
    pub errors: Vec<ir::ErrorModel>,
    pub coefficients: Vec<ir::Coefficient>,
    pub nonlinear: Vec<ir::NonLinearParam>,
    pub lags: Vec<ir::Lag>,
    /// Where each error model, coefficient and non-linear parameter was declared.
    pub error_spans: Vec<Span>,
    pub coefficient_spans: Vec<Span>,
    pub nonlinear_spans: Vec<Span>,
    pub used_inputs: Vec<bool>,
}

/// Temperature semantics of a scalar: an absolute temperature may only be differenced.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Temp {
    /// Not an absolute temperature (may still be a temperature difference).
    Plain,
    /// An absolute temperature (an `absolute` input, or something offset from one).
    Absolute,
    /// A literal temperature such as `20 degC`: absolute next to an absolute, else a difference.
    /// Holds the SI value read as a difference; `Literal` terms carry the absolute value in
    /// their scale.
    Literal { difference: f64 },
}

/// One expanded term while checking.
#[derive(Debug, Clone)]
struct SymTerm {
    scale: Scalar,
    dim: Dim,
    temp: Temp,
    /// Basis factors with the span of the call that made them.
    factors: Vec<(ir::BasisFactor, Span, String)>,
    /// Brings coefficients (has a basis factor or `const`).
    fitted: bool,
    span: Span,
}

impl SymTerm {
    fn scalar(scale: Scalar, dim: Dim, span: Span) -> Self {
        SymTerm {
            scale,
            dim,
            temp: Temp::Plain,
            factors: Vec::new(),
            fitted: false,
            span,
        }
    }
    fn is_scalar(&self) -> bool {
        !self.fitted
    }
}

pub(crate) fn check_errors(decls: &[&ast::ErrorsDecl], st: &Structure, sink: &mut Sink) -> Models {
    let mut cx = Checker {
        st,
        models: Models {
            errors: Vec::new(),
            coefficients: Vec::new(),
            nonlinear: Vec::new(),
            lags: Vec::new(),
            error_spans: Vec::new(),
            coefficient_spans: Vec::new(),
            nonlinear_spans: Vec::new(),
            used_inputs: vec![false; st.inputs.len()],
        },
        defined: HashMap::new(),
        current: String::new(),
        component: None,
        nonlinear_count: HashMap::new(),
        per_error: HashMap::new(),
    };
    for decl in decls {
        for def in &decl.defs {
            cx.definition(def, sink);
        }
    }
    cx.models
}

struct Checker<'a> {
    st: &'a Structure,
    models: Models,
    /// Index of the error model per target, and the span of its `=` definition if any.
    defined: HashMap<(FrameRef, Component), (usize, Option<Span>)>,
    /// Display name of the target being checked, e.g. `Z.tz`.
    current: String,
    /// The one component the value being expanded is for (`beam` depends on it); `None` for a
    /// definition with several targets.
    component: Option<Component>,
    nonlinear_count: HashMap<(String, &'static str), usize>,
    /// Coefficients so far per error model, for their names.
    per_error: HashMap<usize, usize>,
}

impl Checker<'_> {
    fn definition(&mut self, def: &ast::ErrorDef, sink: &mut Sink) {
        // Every target resolved and claimed first, so that a bad one stops the definition
        // before its value is checked (and its diagnostics given) once per target.
        let mut claimed: Vec<(usize, Component, String, Span, f64)> = Vec::new();
        let mut named: HashMap<(FrameRef, Component), Span> = HashMap::new();
        for t in &def.targets {
            let Some((frame, component, display, sign)) = self.target(t, sink) else {
                return;
            };
            if let Some(first) = named.get(&(frame, component)) {
                sink.push(
                    Diagnostic::error(
                        "E0102",
                        format!("`{display}` is named twice in this definition"),
                        t.span,
                    )
                    .with_label("named again here")
                    .with_secondary(*first, "first named here")
                    .with_help("each component takes the terms once: remove one of the two"),
                );
                return;
            }
            named.insert((frame, component), t.span);
            // Written as an ISO 230-1 name (`EC0Y`): a clash then names the component it is.
            let written = t
                .component
                .is_none()
                .then_some((t.frame.node.as_str(), sign));
            let Some(index) =
                self.claim(frame, component, &display, written, t.span, def.add, sink)
            else {
                return;
            };
            claimed.push((index, component, display, t.span, sign));
        }
        let Some((_, _, first, _, _)) = claimed.first() else {
            return;
        };
        // The value is expanded once: a wavelength or time constant it declares `fit` is one
        // parameter (named after the first target), shared by every target's terms.
        self.current = first.clone();
        self.component = match claimed.as_slice() {
            [(_, c, _, _, _)] => Some(*c),
            _ => None,
        };
        let Some(terms) = self.expand(&def.value, sink) else {
            return;
        };
        let several = claimed.len() > 1;
        for (index, component, display, target_span, sign) in claimed {
            self.current = display;
            let mut terms = terms.clone();
            // A location or squareness name carried with the opposite sign (`EC0Y = const` on
            // a frame where it is `−X.rz`): the model is the component's, negated.
            if sign < 0.0 {
                for t in &mut terms {
                    t.scale = match &t.scale {
                        Scalar::Num(v) => Scalar::Num(-v),
                        other => Scalar::Neg(Box::new(other.clone())),
                    };
                }
            }
            self.terms(
                index,
                component,
                terms,
                several.then_some(target_span),
                sink,
            );
        }
    }

    /// The error model of `(frame, component)`: a new one, or the existing one for `+=` and
    /// for the first `=`; a second `=` is an error.
    #[allow(clippy::too_many_arguments)]
    fn claim(
        &mut self,
        frame: FrameRef,
        component: Component,
        display: &str,
        written: Option<(&str, f64)>,
        span: Span,
        add: bool,
        sink: &mut Sink,
    ) -> Option<usize> {
        match self.defined.get(&(frame, component)).copied() {
            // An `=` after `+=` lines only: the model is the sum of all definitions in any
            // order, so the `=` is its one defining line (a robot model adds a compliance
            // term near the joint and defines the offsets in a table further down).
            Some((index, None)) if !add => {
                self.defined.insert((frame, component), (index, Some(span)));
                Some(index)
            }
            Some((index, first)) => {
                if !add {
                    let message = match written {
                        Some((name, sign)) => format!(
                            "`{display}` is defined twice: `{name}` is `{}{display}` on this machine",
                            if sign < 0.0 { "−" } else { "" }
                        ),
                        None => format!("`{display}` is defined twice"),
                    };
                    let help = match written {
                        Some((name, _)) => format!(
                            "use `{name} += …` to add terms to the model of `{display}` defined above"
                        ),
                        None => format!("use `{display} += …` to add terms to an existing model"),
                    };
                    let mut d = Diagnostic::error("E0102", message, span)
                        .with_label("second definition")
                        .with_help(help);
                    if let Some(first) = first {
                        d = d.with_secondary(first, "first defined here");
                    }
                    sink.push(d);
                    return None;
                }
                Some(index)
            }
            None => {
                let index = self.models.errors.len();
                self.models.errors.push(ir::ErrorModel {
                    frame,
                    component,
                    terms: Vec::new(),
                });
                self.models.error_spans.push(span);
                self.defined
                    .insert((frame, component), (index, (!add).then_some(span)));
                Some(index)
            }
        }
    }

    /// Adds the expanded `terms` to error model `index` (the target `self.current`), checking
    /// each against the component's dimension. `target` is the target's span when the
    /// definition names several, for diagnostics to say which one a term does not fit.
    fn terms(
        &mut self,
        index: usize,
        component: Component,
        terms: Vec<SymTerm>,
        target: Option<Span>,
        sink: &mut Sink,
    ) {
        let display = self.current.clone();
        let component_unit = if component.is_rotation() {
            &self.st.units.tilt
        } else {
            &self.st.units.error
        };
        let component_dim = if component.is_rotation() {
            Dim::ANGLE
        } else {
            Dim::LENGTH
        };
        for term in terms {
            if !finite(&term.scale) {
                sink.push(
                    Diagnostic::error(
                        "E0003",
                        "this term's constant factor is too large to represent",
                        term.span,
                    )
                    .with_label("not a finite number")
                    .with_help("numbers must stay within double precision (about 1e308)"),
                );
                continue;
            }
            if matches!(term.temp, Temp::Absolute) {
                sink.push(absolute_temperature(term.span));
                continue;
            }
            if term.fitted {
                self.fitted_term(index, term, component_unit, sink);
            } else if term.dim != component_dim {
                let kind = if component.is_rotation() {
                    "a rotation"
                } else {
                    "a translation"
                };
                let d = Diagnostic::error(
                        "E0202",
                        if term.dim == Dim::DIMENSIONLESS {
                            format!("{kind} error cannot take a dimensionless term")
                        } else {
                            format!("{kind} error cannot take a term of {}", term.dim.describe())
                        },
                        term.span,
                    )
                    .with_label(format!("this fixed term is {}", term.dim.describe()))
                    .with_note(format!(
                        "`{display}` is {}; a term without a fitted factor is a known error and must have that dimension",
                        component_dim.describe()
                    ))
                    .with_help(if term.dim == Dim::DIMENSIONLESS || term.dim == component_dim * Dim::DIMENSIONLESS {
                        format!("give it a unit, e.g. `{} {}`", 1, component_unit.name)
                    } else {
                        "multiply by `const` to fit a coefficient instead, or fix the units".to_string()
                    });
                sink.push(match target {
                    Some(t) => {
                        d.with_secondary(t, format!("this target is {}", component_dim.describe()))
                    }
                    None => d,
                });
            } else {
                let scale = match term.temp {
                    Temp::Literal { difference } => Scalar::Num(difference),
                    _ => term.scale,
                };
                if let Some(model) = self.models.errors.get_mut(index) {
                    model.terms.push(ir::Term {
                        scale,
                        factors: Vec::new(),
                        first: self.models.coefficients.len(),
                        coefficients: 0,
                    });
                }
            }
        }
    }

    fn fitted_term(&mut self, index: usize, term: SymTerm, component_unit: &Unit, sink: &mut Sink) {
        let count: usize = term
            .factors
            .iter()
            .map(|(f, _, _)| f.basis.size())
            .product();
        if count > 100_000 {
            sink.push(
                Diagnostic::error(
                    "E0105",
                    format!("this term has {count} coefficients"),
                    term.span,
                )
                .with_label("too many coefficients")
                .with_help("use fewer knots or harmonics"),
            );
            return;
        }
        let coef_unit = component_unit.div(&display_unit(term.dim, &self.st.units));
        let first = self.models.coefficients.len();
        let sizes: Vec<usize> = term
            .factors
            .iter()
            .map(|(f, _, _)| f.basis.size())
            .collect();
        let prior = *self.per_error.get(&index).unwrap_or(&0);
        self.per_error.insert(index, prior + count);
        for k in 0..count {
            // Row-major multi-index over the factors.
            let mut rest = k;
            let mut parts = Vec::with_capacity(sizes.len());
            for (i, (factor, _, name)) in term.factors.iter().enumerate().rev() {
                let size = sizes.get(i).copied().unwrap_or(1).max(1);
                parts.push(format!("{name}:{}", factor.basis.label(rest % size)));
                rest /= size;
            }
            parts.reverse();
            let label = if parts.is_empty() {
                "const".to_string()
            } else {
                parts.join(" * ")
            };
            self.models.coefficients.push(ir::Coefficient {
                name: format!("{}[{}]", self.current, prior + k),
                label,
                error: index,
                unit: coef_unit.clone(),
            });
            self.models.coefficient_spans.push(term.span);
        }
        if let Some(model) = self.models.errors.get_mut(index) {
            model.terms.push(ir::Term {
                scale: term.scale,
                factors: term.factors.into_iter().map(|(f, _, _)| f).collect(),
                first,
                coefficients: count,
            });
        }
    }

    /// Resolves `X.tx`, `probe.rz`, `tool.tz`, `workpiece.rx`, `EXX`, `xtx` or `EC0Y`, with
    /// the sign the model takes on that component (−1 only for a location or squareness name
    /// carried by a frame with the opposite sense).
    fn target(
        &self,
        t: &ast::Target,
        sink: &mut Sink,
    ) -> Option<(FrameRef, Component, String, f64)> {
        let layout = ir::Layout {
            axes: &self.st.axes,
            tool_chain: &self.st.tool_chain,
            workpiece_chain: &self.st.workpiece_chain,
        };
        let (frame_name, comp_name, comp_span, sign) = match &t.component {
            Some(c) => (t.frame.node.clone(), c.node.clone(), c.span, 1.0),
            None => match ir::alias(&t.frame.node, layout) {
                Ok(Some(a)) => (
                    a.axis.to_string(),
                    a.component.name().to_string(),
                    t.frame.span,
                    a.sign,
                ),
                // Reported where the chains are resolved (E0401).
                Err(ir::AliasError::Unplaced { .. }) => return None,
                Err(e) => {
                    sink.push(
                        Diagnostic::error("E0107", e.to_string(), t.frame.span)
                            .with_label("an ISO 230-1 location name this machine cannot carry")
                            .with_help(e.help()),
                    );
                    return None;
                }
                Ok(None) => {
                    let mut d = Diagnostic::error("E0101", format!("`{}` is not an error component", t.frame.node), t.span)
                        .with_label("expected `FRAME.COMPONENT`")
                        .with_note("write e.g. `X.tx`, an ISO 230-1 name such as `EXX`/`EBX` (component) or `EC0Y`/`EX0C` (location), or a VDI 2617 name such as `xtx`/`xry`");
                    if let Some(s) =
                        suggest(&t.frame.node, self.st.axes.iter().map(|a| a.name.as_str()))
                    {
                        d = d.with_help(format!(
                            "did you mean `{s}.tx` (or another component of `{s}`)?"
                        ));
                    }
                    sink.push(d);
                    return None;
                }
            },
        };
        let component = match Component::ALL.iter().find(|c| c.name() == comp_name) {
            Some(c) => *c,
            None => {
                let mut d = Diagnostic::error("E0106", format!("unknown error component `{comp_name}`"), comp_span)
                    .with_label("not one of tx, ty, tz, rx, ry, rz")
                    .with_note("every frame has six parametric errors: translations tx ty tz and rotations rx ry rz, in its own axes");
                if let Some(s) = suggest(&comp_name, Component::ALL.map(|c| c.name())) {
                    d = d.with_help(format!("did you mean `{s}`?"));
                }
                sink.push(d);
                return None;
            }
        };
        if self.st.broken.contains(&frame_name) {
            return None;
        }
        let frame = if let Some(i) = self.st.axis_index(&frame_name) {
            // An axis outside every chain was reported already (E0401) and the compilation will
            // fail; its models are still checked under a frame that no IR will ever hold, so
            // their own mistakes are reported in the same run.
            self.st
                .axis_frame
                .get(i)
                .copied()
                .flatten()
                .unwrap_or(FrameRef::Tool(usize::MAX - i))
        } else if let Some(i) = self.st.tool_index(&frame_name) {
            FrameRef::ToolEnd(Some(i))
        } else if frame_name == "tool" {
            FrameRef::ToolEnd(None)
        } else if frame_name == "workpiece" {
            FrameRef::WorkpieceEnd
        } else {
            let candidates: Vec<&str> = self
                .st
                .axes
                .iter()
                .map(|a| a.name.as_str())
                .chain(self.st.tools.iter().map(|t| t.name.as_str()))
                .chain(["tool", "workpiece"])
                .collect();
            let mut d = Diagnostic::error(
                "E0101",
                format!("unknown frame `{frame_name}`"),
                t.frame.span,
            )
            .with_label("not an axis, a tool, `tool` or `workpiece`");
            if self.st.input_index(&frame_name).is_some() {
                d = d.with_note(format!("`{frame_name}` is an input; errors belong to frames (axes, tools, the workpiece)"));
            } else if let Some(s) = suggest(&frame_name, candidates.iter().copied()) {
                d = d.with_help(format!("did you mean `{s}`?"));
            }
            sink.push(d);
            return None;
        };
        Some((
            frame,
            component,
            format!("{frame_name}.{}", component.name()),
            sign,
        ))
    }

    /// Expands an expression into a sum of terms.
    fn expand(&mut self, e: &Expr, sink: &mut Sink) -> Option<Vec<SymTerm>> {
        match &e.kind {
            ExprKind::Quantity { value, unit } => {
                let Some(u) = unit else {
                    return Some(vec![SymTerm::scalar(
                        Scalar::Num(*value),
                        Dim::DIMENSIONLESS,
                        e.span,
                    )]);
                };
                let unit = parse_unit(u, sink)?;
                let mut t = SymTerm::scalar(Scalar::Num(unit.to_si(*value)), unit.dim, e.span);
                if unit.dim == Dim::TEMPERATURE {
                    t.temp = Temp::Literal {
                        difference: unit.as_difference().to_si(*value),
                    };
                }
                Some(vec![t])
            }
            ExprKind::Const => Some(vec![SymTerm {
                scale: Scalar::Num(1.0),
                dim: Dim::DIMENSIONLESS,
                temp: Temp::Plain,
                factors: Vec::new(),
                fitted: true,
                span: e.span,
            }]),
            ExprKind::Name(n) => self.variable(n, e.span, sink).map(|t| vec![t]),
            ExprKind::Neg(inner) => {
                let terms = self.expand(inner, sink)?;
                Some(
                    terms
                        .into_iter()
                        .map(|mut t| {
                            t.scale = Scalar::Neg(Box::new(t.scale));
                            if let Temp::Literal { difference } = t.temp {
                                t.temp = Temp::Literal {
                                    difference: -difference,
                                };
                            }
                            t.span = e.span;
                            t
                        })
                        .collect(),
                )
            }
            ExprKind::Binary(op, a, b) => {
                let left = self.expand(a, sink);
                let right = self.expand(b, sink);
                let (left, right) = (left?, right?);
                match op {
                    BinOp::Add | BinOp::Sub => {
                        self.add(*op, e.span, left, a.span, right, b.span, sink)
                    }
                    BinOp::Mul => self.multiply(left, right, e.span, sink),
                    BinOp::Div => self.divide(left, right, e.span, b.span, sink),
                }
            }
            ExprKind::Call { name, args } => self.call(name, args, e.span, sink).map(|t| vec![t]),
        }
    }

    /// The variable of a family or lag: an axis, an input or `time`.
    fn resolve_var(&mut self, n: &str, span: Span, sink: &mut Sink) -> Option<Var> {
        let t = self.variable(n, span, sink)?;
        match t.scale {
            Scalar::Var(v) => Some(v),
            _ => None,
        }
    }

    fn variable(&mut self, n: &str, span: Span, sink: &mut Sink) -> Option<SymTerm> {
        if self.st.broken.iter().any(|b| b == n) {
            return None;
        }
        if let Some(i) = self.st.axis_index(n) {
            let dim = match self.st.axes.get(i).map(|a| a.kind) {
                Some(JointKind::Revolute) => Dim::ANGLE,
                _ => Dim::LENGTH,
            };
            return Some(SymTerm::scalar(Scalar::Var(Var::Axis(i)), dim, span));
        }
        if let Some(i) = self.st.input_index(n) {
            if let Some(u) = self.models.used_inputs.get_mut(i) {
                *u = true;
            }
            let input = self.st.inputs.get(i)?;
            let mut t = SymTerm::scalar(Scalar::Var(Var::Input(i)), input.unit.dim, span);
            if input.absolute {
                t.temp = Temp::Absolute;
            }
            return Some(t);
        }
        if n == "time" {
            return Some(SymTerm::scalar(Scalar::Var(Var::Time), Dim::TIME, span));
        }
        if self.st.tool_index(n).is_some() {
            sink.push(
                Diagnostic::error("E0101", format!("`{n}` is a tool, not a quantity"), span)
                    .with_label("a tool cannot be used in an expression"),
            );
            return None;
        }
        let candidates: Vec<&str> = self
            .st
            .axes
            .iter()
            .map(|a| a.name.as_str())
            .chain(self.st.inputs.iter().map(|i| i.name.as_str()))
            .chain(["time"])
            .collect();
        let mut d = Diagnostic::error("E0101", format!("unknown name `{n}`"), span)
            .with_label("not an axis or an input");
        if let Some(s) = suggest(n, candidates.iter().copied()) {
            d = d.with_help(format!("did you mean `{s}`?"));
        } else if FAMILIES.contains(&n) {
            d = d.with_help(format!("`{n}` is a factor family: call it, e.g. `{n}(X)`"));
        }
        sink.push(d);
        None
    }

    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        op: BinOp,
        span: Span,
        left: Vec<SymTerm>,
        lspan: Span,
        mut right: Vec<SymTerm>,
        rspan: Span,
        sink: &mut Sink,
    ) -> Option<Vec<SymTerm>> {
        if op == BinOp::Sub {
            for t in &mut right {
                t.scale = Scalar::Neg(Box::new(t.scale.clone()));
                if let Temp::Literal { difference } = t.temp {
                    t.temp = Temp::Literal {
                        difference: -difference,
                    };
                }
            }
        }
        // Known scalars added together must agree in dimension; fitted terms each carry their
        // own coefficients and so their own derived units.
        let ls: Vec<&SymTerm> = left.iter().filter(|t| t.is_scalar()).collect();
        let rs: Vec<&SymTerm> = right.iter().filter(|t| t.is_scalar()).collect();
        if let (Some(l), Some(r)) = (ls.first(), rs.first()) {
            let bare =
                |t: &SymTerm| t.dim == Dim::DIMENSIONLESS && matches!(t.scale, Scalar::Num(_));
            if l.dim != r.dim {
                let mut d = dimension_mismatch(span, lspan, l.dim, rspan, r.dim);
                if bare(l) || bare(r) {
                    let other = if bare(l) { r.dim } else { l.dim };
                    d = d.with_help(format!(
                        "give the number a unit of {}, e.g. `375 mm`",
                        other.describe()
                    ));
                }
                sink.push(d);
                return None;
            }
            // Temperature: absolute − absolute is a difference; absolute ± rise stays absolute.
            if ls.len() == 1 && rs.len() == 1 && left.len() == 1 && right.len() == 1 {
                let (lt, rt) = (l.temp, r.temp);
                let mut l = left.into_iter().next()?;
                let r = right.into_iter().next()?;
                let (temp, lscale, rscale) = match (lt, rt) {
                    (Temp::Absolute, Temp::Absolute) if op == BinOp::Sub => {
                        (Temp::Plain, l.scale, r.scale)
                    }
                    (Temp::Absolute, Temp::Literal { .. }) if op == BinOp::Sub => {
                        (Temp::Plain, l.scale, r.scale)
                    }
                    (Temp::Literal { .. }, Temp::Absolute) if op == BinOp::Sub => {
                        (Temp::Plain, l.scale, r.scale)
                    }
                    (Temp::Absolute, Temp::Literal { difference }) => {
                        (Temp::Absolute, l.scale, Scalar::Num(difference))
                    }
                    (Temp::Absolute, Temp::Plain) | (Temp::Plain, Temp::Absolute) => {
                        (Temp::Absolute, l.scale, r.scale)
                    }
                    (Temp::Literal { difference: a }, Temp::Literal { difference: b }) => {
                        (Temp::Literal { difference: a + b }, l.scale, r.scale)
                    }
                    (Temp::Literal { difference }, _) => {
                        (Temp::Plain, Scalar::Num(difference), r.scale)
                    }
                    (_, Temp::Literal { difference }) => {
                        (Temp::Plain, l.scale, Scalar::Num(difference))
                    }
                    _ => (Temp::Plain, l.scale, r.scale),
                };
                if matches!(temp, Temp::Absolute)
                    && matches!((lt, rt), (Temp::Absolute, Temp::Absolute))
                {
                    sink.push(absolute_temperature(span));
                    return None;
                }
                l.scale = Scalar::Add(Box::new(lscale), Box::new(rscale));
                l.temp = temp;
                l.span = span;
                return Some(vec![l]);
            }
        }
        let mut out = left;
        out.extend(right);
        Some(out)
    }

    fn multiply(
        &mut self,
        left: Vec<SymTerm>,
        right: Vec<SymTerm>,
        span: Span,
        sink: &mut Sink,
    ) -> Option<Vec<SymTerm>> {
        // Products of sums multiply out: refuse before the term count explodes.
        if left.len().saturating_mul(right.len()) > MAX_TERMS {
            sink.push(
                Diagnostic::error(
                    "E0105",
                    format!("multiplying this out gives more than {MAX_TERMS} terms"),
                    span,
                )
                .with_label("too many terms")
                .with_help("write the model as a few products of families, not a product of sums"),
            );
            return None;
        }
        let mut out = Vec::with_capacity(left.len() * right.len());
        for a in &left {
            for b in &right {
                for t in [a, b] {
                    if matches!(t.temp, Temp::Absolute) {
                        sink.push(absolute_temperature(t.span));
                        return None;
                    }
                }
                for (fa, sa, _) in &a.factors {
                    if let Some((_, sb, _)) = b.factors.iter().find(|(fb, _, _)| fb.var == fa.var) {
                        sink.push(
                            Diagnostic::error(
                                "E0307",
                                "two basis factors of the same variable in one product",
                                *sb,
                            )
                            .with_label("second factor of this variable")
                            .with_secondary(*sa, "first factor")
                            .with_help("use one family with a higher degree or more knots instead"),
                        );
                        return None;
                    }
                }
                let lit = |t: &SymTerm| match t.temp {
                    Temp::Literal { difference } => Scalar::Num(difference),
                    _ => t.scale.clone(),
                };
                let mut factors = a.factors.clone();
                factors.extend(b.factors.iter().cloned());
                out.push(SymTerm {
                    scale: simplify_mul(lit(a), lit(b)),
                    dim: a.dim * b.dim,
                    temp: Temp::Plain,
                    factors,
                    fitted: a.fitted || b.fitted,
                    span,
                });
            }
        }
        Some(out)
    }

    fn divide(
        &mut self,
        left: Vec<SymTerm>,
        right: Vec<SymTerm>,
        span: Span,
        rspan: Span,
        sink: &mut Sink,
    ) -> Option<Vec<SymTerm>> {
        if let Some(t) = right.iter().find(|t| t.fitted) {
            sink.push(
                Diagnostic::error("E0307", "a fitted factor cannot divide", t.span)
                    .with_label("basis factor in a denominator")
                    .with_note("the model must stay linear in the coefficients β"),
            );
            return None;
        }
        let divisor = self.collapse(right, rspan, sink)?;
        if let Scalar::Num(v) = divisor.scale {
            if v == 0.0 {
                sink.push(
                    Diagnostic::error("E0003", "division by zero", rspan)
                        .with_label("this is zero"),
                );
                return None;
            }
        }
        let mut out = Vec::with_capacity(left.len());
        for mut t in left {
            if matches!(t.temp, Temp::Absolute) {
                sink.push(absolute_temperature(t.span));
                return None;
            }
            if let Temp::Literal { difference } = t.temp {
                t.scale = Scalar::Num(difference);
                t.temp = Temp::Plain;
            }
            t.scale = Scalar::Div(Box::new(t.scale), Box::new(divisor.scale.clone()));
            t.dim = t.dim / divisor.dim;
            t.span = span;
            out.push(t);
        }
        Some(out)
    }

    /// Sums known scalar terms into one (they were dimension-checked when added).
    fn collapse(&mut self, terms: Vec<SymTerm>, span: Span, sink: &mut Sink) -> Option<SymTerm> {
        let mut it = terms.into_iter();
        let mut acc = it.next()?;
        if matches!(acc.temp, Temp::Absolute) {
            sink.push(absolute_temperature(acc.span));
            return None;
        }
        if let Temp::Literal { difference } = acc.temp {
            acc.scale = Scalar::Num(difference);
        }
        for t in it {
            acc.scale = Scalar::Add(Box::new(acc.scale), Box::new(t.scale));
        }
        acc.temp = Temp::Plain;
        acc.span = span;
        Some(acc)
    }

    fn call(
        &mut self,
        name: &ast::Name,
        args: &[Arg],
        span: Span,
        sink: &mut Sink,
    ) -> Option<SymTerm> {
        let f = name.node.as_str();
        match f {
            "sin" | "cos" => return self.trig(f, args, span, sink),
            "lag" => return self.lag(args, span, sink),
            "warmup" => return self.warmup(args, span, sink),
            "beam" => return self.beam(args, span, sink),
            "pow" => {
                sink.push(
                    Diagnostic::error("E0308", "`pow` is written inside `lag`", name.span)
                        .with_label("a power of an input outside a lag")
                        .with_note("a power of an input is a heat source: its heat reaches the structure through a lag")
                        .with_help("e.g. `lag(pow(S / 1000 rpm, 1.5), tau fit 30 min) * const`"),
                );
                self.mark_used(args);
                return None;
            }
            _ => {}
        }
        if !FAMILIES.contains(&f) {
            let mut d = Diagnostic::error("E0104", format!("unknown function `{f}`"), name.span)
                .with_label("not a factor family");
            if let Some(s) = suggest(
                f,
                FAMILIES
                    .iter()
                    .copied()
                    .chain(["sin", "cos", "lag", "warmup", "beam"]),
            ) {
                d = d.with_help(format!("did you mean `{s}`?"));
            } else {
                d = d.with_note(format!(
                    "factor families: {}, and the functions sin, cos, lag, warmup, beam",
                    FAMILIES.join(", ")
                ));
            }
            sink.push(d);
            return None;
        }
        let mut opts = Options::new(f, args, span, sink)?;
        let (var_name, var_span) = opts.variable(sink)?;
        let var = self.resolve_var(&var_name, var_span, sink)?;
        let basis = self.family(f, var, &var_name, var_span, &mut opts, sink)?;
        opts.finish(sink)?;
        let factor_var = match (f, var) {
            ("backlash" | "direction", Var::Axis(i)) => Var::Direction(i),
            _ => var,
        };
        Some(SymTerm {
            scale: Scalar::Num(1.0),
            dim: Dim::DIMENSIONLESS,
            temp: Temp::Plain,
            factors: vec![(
                ir::BasisFactor {
                    var: factor_var,
                    basis,
                },
                span,
                format!("{f}({var_name})"),
            )],
            fitted: true,
            span,
        })
    }

    /// The declared range of a family's variable, in SI, and its dimension.
    fn range_of(
        &self,
        var: Var,
        name: &str,
        span: Span,
        family: &str,
        sink: &mut Sink,
    ) -> Option<([f64; 2], Dim, Unit)> {
        match var {
            Var::Axis(i) => {
                let a = self.st.axes.get(i)?;
                let (dim, unit) = match a.kind {
                    JointKind::Prismatic => (Dim::LENGTH, self.st.units.length.clone()),
                    JointKind::Revolute => (Dim::ANGLE, self.st.units.angle.clone()),
                };
                Some((a.range, dim, unit))
            }
            Var::Input(i) => {
                let input = self.st.inputs.get(i)?;
                match self.st.input_ranges.get(i).copied().flatten() {
                    Some(r) => Some((r, input.unit.dim, input.unit.clone())),
                    None => {
                        sink.push(
                            Diagnostic::error(
                                "E0305",
                                format!("`{family}` needs the range of input `{name}`"),
                                span,
                            )
                            .with_label("this input has no declared range")
                            .with_note("families are normalised over the variable's range")
                            .with_help(format!(
                                "declare it, e.g. `input {name} : … range LO .. HI`"
                            )),
                        );
                        None
                    }
                }
            }
            _ => {
                sink.push(
                    Diagnostic::error(
                        "E0305",
                        format!("`{family}` needs an axis or a ranged input"),
                        span,
                    )
                    .with_label("not a ranged variable"),
                );
                None
            }
        }
    }

    fn family(
        &mut self,
        f: &str,
        var: Var,
        var_name: &str,
        var_span: Span,
        opts: &mut Options,
        sink: &mut Sink,
    ) -> Option<Basis> {
        let revolute = matches!(var, Var::Axis(i) if self.st.axes.get(i).map(|a| a.kind) == Some(JointKind::Revolute));
        let basis = match f {
            "linear" => {
                let (r, ..) = self.range_of(var, var_name, var_span, f, sink)?;
                Basis::linear(r[0], r[1])
            }
            "poly" => {
                let (r, ..) = self.range_of(var, var_name, var_span, f, sink)?;
                let degree = opts.integer("degree", 1, 5, sink)?.unwrap_or(2);
                Basis::legendre(r[0], r[1], degree as u32)
            }
            "spline" | "straightness" => {
                let (r, _, unit) = self.range_of(var, var_name, var_span, f, sink)?;
                let knots = opts.knots(r, &unit, sink)?.unwrap_or_default();
                let (degree, smooth) = opts.degree_smooth(sink)?;
                let no_once = opts.flag("no_once_per_rev");
                if no_once && !revolute {
                    sink.push(
                        Diagnostic::error(
                            "E0305",
                            "`no_once_per_rev` applies to a revolute axis only",
                            var_span,
                        )
                        .with_label(format!("`{var_name}` is not a revolute axis"))
                        .with_help(
                            "for a straightness along a prismatic axis use `straightness(…)`",
                        ),
                    );
                    return None;
                }
                let detrend = if f == "straightness" {
                    Detrend::Line
                } else if no_once {
                    Detrend::OncePerRev
                } else {
                    Detrend::None
                };
                Basis::spline(r[0], r[1], knots, degree, smooth, detrend)
            }
            "fourier" if revolute => {
                // Per revolution: the fundamental is the revolution itself (§3.2.4).
                if let Some(o) = opts.take("wavelength") {
                    sink.push(
                        Diagnostic::error(
                            "E0305",
                            "`wavelength` is for a `fourier` along a variable that is not an angle",
                            o.name.span,
                        )
                        .with_label(format!("`{var_name}` is a revolute axis"))
                        .with_note("along a revolute axis the harmonics are per revolution: the fundamental is one turn")
                        .with_help(format!("write `fourier({var_name}, harmonics …)` without a wavelength")),
                    );
                    return None;
                }
                let h = opts.harmonics(sink)?;
                Basis::fourier(h)
            }
            "fourier" => {
                let (r, dim, unit) = self.range_of(var, var_name, var_span, f, sink)?;
                if !opts.has("wavelength") {
                    sink.push(
                        Diagnostic::error(
                            "E0305",
                            format!("`fourier` along `{var_name}` needs a `wavelength`"),
                            var_span,
                        )
                        .with_label(format!("`{var_name}` is not an angle: which fundamental?"))
                        .with_note("only a revolute axis has a natural period (one turn)")
                        .with_help(format!("give the fundamental, e.g. `fourier({var_name}, harmonics 1..2, wavelength fit 25.4 mm)`")),
                    );
                    return None;
                }
                let wavelength = self.wavelength(r, dim, &unit, var_name, opts, sink)?;
                let h = opts.harmonics(sink)?;
                Basis::fourier_along(h, wavelength)
            }
            "periodic" => {
                let (r, dim, unit) = self.range_of(var, var_name, var_span, f, sink)?;
                let wavelength = self.wavelength(r, dim, &unit, var_name, opts, sink)?;
                let phase = opts
                    .quantity("phase", dim, &unit, sink)?
                    .map(|(v, _, _)| v)
                    .unwrap_or(0.0);
                let knots = match opts.integer("knots", 0, 50, sink)? {
                    Some(n) => basis::equally_spaced_knots(n as usize).ok()?,
                    None => basis::equally_spaced_knots(2).ok()?,
                };
                let (degree, smooth) = opts.degree_smooth(sink)?;
                Basis::periodic(wavelength, phase, knots, degree, smooth)
            }
            "backlash" | "direction" => {
                if !matches!(var, Var::Axis(_)) {
                    sink.push(
                        Diagnostic::error("E0305", format!("`{f}` applies to an axis only"), var_span)
                            .with_label(format!("`{var_name}` is not an axis"))
                            .with_note("a backlash follows an axis' direction of motion (`dir_AXIS` in the data)"),
                    );
                    return None;
                }
                Ok(Basis::Sign)
            }
            _ => return None,
        };
        match basis {
            Ok(b) => Some(b),
            Err(e) => {
                sink.push(
                    Diagnostic::error("E0105", format!("invalid `{f}`: {e}"), opts.span)
                        .with_label("these options do not define a basis"),
                );
                None
            }
        }
    }

    /// The `wavelength [fit] λ` option of `periodic` or `fourier` along a variable of range `r`:
    /// positive, and no longer than the range (a period must repeat within it).
    fn wavelength(
        &mut self,
        r: [f64; 2],
        dim: Dim,
        unit: &Unit,
        var_name: &str,
        opts: &mut Options,
        sink: &mut Sink,
    ) -> Option<Wavelength> {
        let (tau, tau_span, fitted) = opts.required_quantity("wavelength", dim, unit, sink)?;
        if !(tau > 0.0) {
            sink.push(
                Diagnostic::error("E0105", "the wavelength must be positive", tau_span)
                    .with_label("not positive"),
            );
            return None;
        }
        if tau > r[1] - r[0] + 1e-12 {
            sink.push(
                        Diagnostic::error("E0303", format!("the wavelength is longer than the range of `{var_name}`"), tau_span)
                            .with_label(format!(
                                "{} {} > range {} {}",
                                fmt_num(unit.from_si(tau) - unit.from_si(0.0)),
                                unit.name,
                                fmt_num(unit.from_si(r[1]) - unit.from_si(r[0])),
                                unit.name
                            ))
                            .with_note("a periodic error must repeat within the range to be told apart from the ordinary error")
                            .with_help("use `spline` for slow variations, or check the wavelength's unit"),
                    );
            return None;
        }
        let wavelength = if fitted {
            let index = self.nonlinear("wavelength", tau, unit.as_difference(), tau_span);
            Wavelength::Fitted(NonLinear { index })
        } else {
            Wavelength::Fixed(tau)
        };
        Some(wavelength)
    }

    fn nonlinear(&mut self, kind: &'static str, value: f64, unit: Unit, span: Span) -> usize {
        let key = (self.current.clone(), kind);
        let k = self.nonlinear_count.entry(key).or_insert(0);
        let name = if *k == 0 {
            format!("{}.{kind}", self.current)
        } else {
            format!("{}.{kind}[{}]", self.current, *k)
        };
        *k += 1;
        let index = self.models.nonlinear.len();
        self.models.nonlinear.push(ir::NonLinearParam {
            name,
            value,
            fitted: true,
            unit,
        });
        self.models.nonlinear_spans.push(span);
        index
    }

    fn trig(&mut self, f: &str, args: &[Arg], span: Span, sink: &mut Sink) -> Option<SymTerm> {
        let [Arg::Positional(arg)] = args else {
            sink.push(
                Diagnostic::error("E0105", format!("`{f}` takes one angle"), span)
                    .with_label("expected one argument"),
            );
            return None;
        };
        let terms = self.expand(arg, sink)?;
        if terms.iter().any(|t| t.fitted) {
            sink.push(
                Diagnostic::error(
                    "E0307",
                    format!("a fitted factor cannot be inside `{f}`"),
                    arg.span,
                )
                .with_label("basis factor inside a function")
                .with_note("the model must stay linear in the coefficients β"),
            );
            return None;
        }
        let inner = self.collapse(terms, arg.span, sink)?;
        if inner.dim != Dim::ANGLE && inner.dim != Dim::DIMENSIONLESS {
            sink.push(
                Diagnostic::error(
                    "E0205",
                    format!("`{f}` takes an angle, but this is {}", inner.dim.describe()),
                    arg.span,
                )
                .with_label("expected an angle"),
            );
            return None;
        }
        let scale = if f == "sin" {
            Scalar::Sin(Box::new(inner.scale))
        } else {
            Scalar::Cos(Box::new(inner.scale))
        };
        Some(SymTerm::scalar(scale, Dim::DIMENSIONLESS, span))
    }

    /// `lag(SOURCE, tau [fit] T [, from U])`: a known scalar, the lag state of an input. The
    /// source is an input, an input over a reference value (`S / 1000 rpm`), a known power of
    /// either (`pow(S / 1000 rpm, 1.5)`: a heat source), or a lag itself (a second stage).
    fn lag(&mut self, args: &[Arg], span: Span, sink: &mut Sink) -> Option<SymTerm> {
        let chain = self.lag_chain(args, span, 1, sink)?;
        let lag = self.models.lags.len();
        self.models.lags.push(chain.lag);
        let mut t = SymTerm::scalar(Scalar::Var(Var::Lag(lag)), chain.dim, span);
        if chain.absolute {
            t.temp = Temp::Absolute;
        }
        Some(t)
    }

    /// `warmup(time, tau [fit] T)`: a known scalar, `1 − e^{−(t − t₀)/τ}` from each run's first
    /// row — the step response of a unit lag (thesis eq. 3.41–3.48 with a heat source switched
    /// on at the run's start and nothing measured). It is a lag whose drive is the constant 1
    /// from rest, so that its states, its fitted τ and both engines are the lags' own.
    fn warmup(&mut self, args: &[Arg], span: Span, sink: &mut Sink) -> Option<SymTerm> {
        let mut opts = Options::new("warmup", args, span, sink)?;
        let (var_name, var_span) = opts.variable(sink)?;
        if var_name != "time" {
            sink.push(
                Diagnostic::error("E0305", "`warmup` runs in `time` only", var_span)
                    .with_label(format!("`{var_name}` is not `time`"))
                    .with_help("write `warmup(time, tau 30 min)`; a warm-up that follows an input is `lag(INPUT, tau …)`"),
            );
            self.mark_used(args);
            return None;
        }
        let time_unit = self.st.units.time.clone();
        let (tau, tau_span, fitted) = opts.required_quantity("tau", Dim::TIME, &time_unit, sink)?;
        opts.finish(sink)?;
        time_constant(tau, tau_span, sink)?;
        let index = self.nonlinear("tau", tau, time_unit, tau_span);
        if let Some(p) = self.models.nonlinear.get_mut(index) {
            p.fitted = fitted;
        }
        let lag = self.models.lags.len();
        self.models.lags.push(ir::Lag {
            input: 0,
            tau: NonLinear { index },
            source: ir::LagSource::default(),
            tau2: None,
            from: None,
            warmup: true,
        });
        Some(SymTerm::scalar(
            Scalar::Var(Var::Lag(lag)),
            Dim::DIMENSIONLESS,
            span,
        ))
    }

    /// One stage of a lag and, through its source, the stages inside it (at most two).
    fn lag_chain(
        &mut self,
        args: &[Arg],
        span: Span,
        depth: usize,
        sink: &mut Sink,
    ) -> Option<LagChain> {
        let mut opts = Options::new("lag", args, span, sink)?;
        let source = *opts.positional.first()?;
        let inner = match &source.kind {
            ExprKind::Call { name, args } if name.node == "lag" => {
                if depth >= 2 {
                    sink.push(
                        Diagnostic::error("E0309", "a lag of a lag of a lag", source.span)
                            .with_label("third stage")
                            .with_note("a cascade has at most two stages: `lag(lag(T, tau 10 min), tau 2 h)`"),
                    );
                    self.mark_used(args);
                    return None;
                }
                self.lag_chain(args, source.span, depth + 1, sink)?
            }
            ExprKind::Call { name, args } if name.node == "pow" => {
                self.lag_power(args, source.span, sink)?
            }
            _ => self.lag_input(source, sink)?,
        };
        let mut chain = inner;
        let time_unit = self.st.units.time.clone();
        let (tau, tau_span, fitted) = opts.required_quantity("tau", Dim::TIME, &time_unit, sink)?;
        if let Some(o) = opts.take("from") {
            let OptionValue::Expr(e) = &o.value else {
                sink.push(
                    Diagnostic::error("E0105", "`from` takes a value of the input", o.value.span())
                        .with_label("expected a quantity"),
                );
                return None;
            };
            if let Some(first) = chain.from_span {
                sink.push(
                    Diagnostic::error(
                        "E0309",
                        "the initial state of this cascade is declared twice",
                        o.name.span,
                    )
                    .with_label("second `from`")
                    .with_secondary(first, "first declared here")
                    .with_note("both stages start settled at the one value held before the run"),
                );
                return None;
            }
            let input = self.st.inputs.get(chain.lag.input)?;
            let what = format!("the initial value of `{}`", input.name);
            let value = quantity_of(e, input.unit.dim, &input.unit, input.absolute, &what, sink)?;
            chain.lag.from = Some(value);
            chain.from_span = Some(o.name.span);
        }
        opts.finish(sink)?;
        time_constant(tau, tau_span, sink)?;
        let index = self.nonlinear("tau", tau, time_unit, tau_span);
        if let Some(p) = self.models.nonlinear.get_mut(index) {
            p.fitted = fitted;
        }
        if depth == 1 && chain.staged {
            chain.lag.tau2 = Some(NonLinear { index });
        } else {
            chain.lag.tau = NonLinear { index };
            chain.staged = true;
        }
        Some(chain)
    }

    /// Marks the inputs named in rejected arguments as used, so that one mistake does not also
    /// report them as never used.
    fn mark_used(&mut self, args: &[Arg]) {
        fn walk(e: &Expr, out: &mut Vec<String>) {
            match &e.kind {
                ExprKind::Name(n) => out.push(n.clone()),
                ExprKind::Neg(a) => walk(a, out),
                ExprKind::Binary(_, a, b) => {
                    walk(a, out);
                    walk(b, out);
                }
                ExprKind::Call { args, .. } => args.iter().for_each(|a| {
                    if let Arg::Positional(e) = a {
                        walk(e, out)
                    }
                }),
                ExprKind::Quantity { .. } | ExprKind::Const => {}
            }
        }
        let mut names = Vec::new();
        for a in args {
            match a {
                Arg::Positional(e) => walk(e, &mut names),
                Arg::Option(o) => match &o.value {
                    OptionValue::Expr(e) => walk(e, &mut names),
                    OptionValue::At { items, .. } => items.iter().for_each(|e| walk(e, &mut names)),
                    _ => {}
                },
            }
        }
        for n in names {
            if let Some(i) = self.st.input_index(&n) {
                if let Some(u) = self.models.used_inputs.get_mut(i) {
                    *u = true;
                }
            }
        }
    }

    /// The source of a lag that is an input, or an input divided by a reference value.
    fn lag_input(&mut self, e: &Expr, sink: &mut Sink) -> Option<LagChain> {
        let (name_expr, reference) = match &e.kind {
            ExprKind::Binary(BinOp::Div, a, b) if matches!(a.kind, ExprKind::Name(_)) => {
                (a.as_ref(), Some(b.as_ref()))
            }
            _ => (e, None),
        };
        let ExprKind::Name(var_name) = &name_expr.kind else {
            sink.push(
                Diagnostic::error("E0305", "`lag` applies to an input only", e.span)
                    .with_label("not an input")
                    .with_help(
                        "a lag takes an input, `S / 1000 rpm`, `pow(S / 1000 rpm, 1.5)` or a lag",
                    ),
            );
            return None;
        };
        let var = self.resolve_var(var_name, name_expr.span, sink)?;
        let Var::Input(input) = var else {
            sink.push(
                Diagnostic::error("E0305", "`lag` applies to an input only", name_expr.span)
                    .with_label(format!("`{var_name}` is not an input"))
                    .with_note("a lag follows a measured input such as a temperature (thesis eq. 3.41–3.48)"),
            );
            return None;
        };
        let decl = self.st.inputs.get(input)?;
        let mut chain = LagChain {
            lag: ir::Lag {
                input,
                tau: NonLinear { index: 0 },
                source: ir::LagSource::default(),
                tau2: None,
                from: None,
                warmup: false,
            },
            dim: decl.unit.dim,
            absolute: decl.absolute,
            staged: false,
            from_span: None,
        };
        if let Some(r) = reference {
            if decl.absolute {
                sink.push(
                    Diagnostic::error("E0308", "an absolute temperature cannot be scaled", e.span)
                        .with_label("absolute temperature over a value")
                        .with_note(
                            "an absolute temperature has an arbitrary zero; lag it as it is",
                        ),
                );
                return None;
            }
            let c = constant(r, false, sink)?;
            if !(c.value > 0.0) {
                sink.push(
                    Diagnostic::error(
                        "E0308",
                        "the reference value of a heat source must be positive",
                        r.span,
                    )
                    .with_label("not positive"),
                );
                return None;
            }
            chain.lag.source.reference = c.value;
            chain.dim = chain.dim / c.dim;
        }
        Some(chain)
    }

    /// `pow(SOURCE, n)` as the source of a lag: a heat source that grows as a known power of
    /// an input (bearing friction with spindle speed, losses with power).
    fn lag_power(&mut self, args: &[Arg], span: Span, sink: &mut Sink) -> Option<LagChain> {
        let [Arg::Positional(base), Arg::Positional(exponent)] = args else {
            sink.push(
                Diagnostic::error("E0308", "`pow` takes an input and a power", span)
                    .with_label("expected two arguments")
                    .with_help("e.g. `pow(S / 1000 rpm, 1.5)`"),
            );
            return None;
        };
        let n = match &exponent.kind {
            ExprKind::Quantity { value, unit: None } => *value,
            _ => {
                sink.push(
                    Diagnostic::error("E0308", "the power must be a plain number", exponent.span)
                        .with_label("expected a number without unit")
                        .with_note("the exponent of a heat source is known, e.g. 1.5"),
                );
                return None;
            }
        };
        if !(n > 0.0 && n <= 10.0) {
            sink.push(
                Diagnostic::error(
                    "E0308",
                    format!("the power {n} is out of bounds"),
                    exponent.span,
                )
                .with_label("must be above 0 and at most 10"),
            );
            return None;
        }
        let mut chain = self.lag_input(base, sink)?;
        if chain.absolute {
            sink.push(absolute_temperature(base.span));
            return None;
        }
        if n.fract() == 0.0 {
            chain.dim = chain.dim.powi(n as i32);
        } else if !chain.dim.is_dimensionless() {
            sink.push(
                Diagnostic::error(
                    "E0308",
                    format!("a power {n} of {} has no unit", chain.dim.describe()),
                    base.span,
                )
                .with_label("not dimensionless")
                .with_help("divide by a reference value, e.g. `pow(S / 1000 rpm, 1.5)`"),
            );
            return None;
        }
        chain.lag.source.power = n;
        Some(chain)
    }
}

impl Checker<'_> {
    /// `beam(A, ends at (x₀, x₁) U, mean at (T₀, T₁))` or `beam(A, ends at (x₀, x₁) U,
    /// upper at (…), lower at (…), gap d, across y|z)`: the stress-free thermal deformation of
    /// a beam along prismatic axis A (thesis §3.4.3, eq. 3.57–3.62) per unit coefficient of
    /// expansion, for the one component being defined. The temperatures (rises from the
    /// reference state) are known scalars at the two ends, linear in between and beyond
    /// (eq. 3.56 along the beam); with `s = q − x₀`, `L = x₁ − x₀`, mean `T̄`, gradient `G`
    /// across the beam (`(upper − lower)/gap`):
    ///
    /// - expansion along the beam (eq. 3.58): `E = ∫T̄ = T̄₀s + (T̄₁ − T̄₀)s²/(2L)`;
    /// - bending angle about `g × u` (eq. 3.59–3.60): `R = ∫G = G₀s + (G₁ − G₀)s²/(2L)`;
    /// - deflection along `−g` (eq. 3.61–3.62): `D = ∫∫G = G₀s²/2 + (G₁ − G₀)s³/(6L)`;
    ///
    /// the component's value is the projection of `u E − g D` (translations, length × K) or
    /// `(g × u) R` (rotations, angle × K) on its own axis; times a coefficient of expansion
    /// (`11.5 um/m/K * beam(…)`, or `beam(…) * const` to fit it) it is the parametric error.
    fn beam(&mut self, args: &[Arg], span: Span, sink: &mut Sink) -> Option<SymTerm> {
        // Its temperatures count as used even when the call is rejected: one mistake, one
        // diagnostic.
        self.mark_used(args);
        let mut opts = Options::new("beam", args, span, sink)?;
        let (var_name, var_span) = opts.variable(sink)?;
        let var = self.resolve_var(&var_name, var_span, sink)?;
        let axis = match var {
            Var::Axis(i) => self
                .st
                .axes
                .get(i)
                .filter(|a| a.kind == JointKind::Prismatic)
                .map(|a| (i, a.direction)),
            _ => None,
        };
        let Some((axis, u)) = axis else {
            sink.push(
                Diagnostic::error("E0305", "`beam` runs along a prismatic axis", var_span)
                    .with_label(format!("`{var_name}` is not a prismatic axis"))
                    .with_note("the beam's coordinate is the axis position (thesis §3.4.3)"),
            );
            return None;
        };
        let Some(component) = self.component else {
            sink.push(
                Diagnostic::error(
                    "E0310",
                    "`beam` gives a different error to each component",
                    span,
                )
                .with_label("in a definition with several targets")
                .with_help(
                    "write one definition per component: `X.tz += 11.5 um/m/K * beam(X, …)`",
                ),
            );
            return None;
        };
        let length_unit = self.st.units.length.clone();
        let ends = opts.take("ends");
        let ends = match ends.map(|o| &o.value) {
            Some(OptionValue::At { items, unit, .. }) if items.len() == 2 => {
                let unit = match unit {
                    Some(u) => parse_unit(u, sink)?.as_difference(),
                    None => length_unit.clone(),
                };
                let mut v = [0.0; 2];
                for (slot, item) in v.iter_mut().zip(items) {
                    *slot =
                        quantity_of(item, Dim::LENGTH, &unit, false, "the end of a beam", sink)?;
                }
                v
            }
            _ => {
                sink.push(
                    Diagnostic::error(
                        "E0105",
                        "`beam` needs its two ends",
                        ends.map(|o| o.value.span()).unwrap_or(span),
                    )
                    .with_label("expected `ends at (x₀, x₁) mm`")
                    .with_help("e.g. `beam(X, ends at (0, 800) mm, mean at (T_0, T_1))`"),
                );
                return None;
            }
        };
        let length = ends[1] - ends[0];
        if !(length > 0.0) {
            sink.push(
                Diagnostic::error("E0304", "the ends of the beam are equal or inverted", span)
                    .with_label("the second end must be beyond the first"),
            );
            return None;
        }
        let mean = self.beam_pair(&mut opts, "mean", span, sink)?;
        let upper = self.beam_pair(&mut opts, "upper", span, sink)?;
        let lower = self.beam_pair(&mut opts, "lower", span, sink)?;
        let gap = opts.quantity("gap", Dim::LENGTH, &length_unit, sink)?;
        let across = opts.take("across").map(|o| (&o.value, o.value.span()));
        opts.finish(sink)?;
        let across = match across {
            None => None,
            Some((
                OptionValue::Expr(Expr {
                    kind: ExprKind::Name(n),
                    ..
                }),
                at,
            )) => match n.as_str() {
                "x" => Some(([1.0, 0.0, 0.0], at)),
                "y" => Some(([0.0, 1.0, 0.0], at)),
                "z" => Some(([0.0, 0.0, 1.0], at)),
                _ => None,
            }
            .or_else(|| {
                sink.push(
                    Diagnostic::error("E0105", "`across` takes `x`, `y` or `z`", at)
                        .with_label("not a direction"),
                );
                None
            }),
            Some((_, at)) => {
                sink.push(
                    Diagnostic::error("E0105", "`across` takes `x`, `y` or `z`", at)
                        .with_label("not a direction"),
                );
                return None;
            }
        };
        let (mean, gradient) = match (mean, upper, lower, gap, across) {
            (Some(m), None, None, None, None) => (m, None),
            (None, Some(up), Some(lo), Some((d, d_span, _)), Some((g, g_span))) => {
                if !(d > 0.0) {
                    sink.push(
                        Diagnostic::error("E0105", "the gap must be positive", d_span)
                            .with_label("not positive"),
                    );
                    return None;
                }
                let dot = g[0] * u[0] + g[1] * u[1] + g[2] * u[2];
                if dot.abs() > 1e-9 {
                    sink.push(
                        Diagnostic::error("E0310", "the gradient must be across the beam", g_span)
                            .with_label(format!("`{var_name}` runs along this direction")),
                    );
                    return None;
                }
                let half =
                    |a: &Scalar, b: &Scalar| mul(Scalar::Num(0.5), add(a.clone(), b.clone()));
                let grad =
                    |a: &Scalar, b: &Scalar| mul(Scalar::Num(1.0 / d), sub(a.clone(), b.clone()));
                (
                    [half(&up[0], &lo[0]), half(&up[1], &lo[1])],
                    Some(([grad(&up[0], &lo[0]), grad(&up[1], &lo[1])], g)),
                )
            }
            _ => {
                sink.push(
                    Diagnostic::error("E0105", "`beam` needs `mean at (…)`, or `upper`, `lower`, `gap` and `across`", span)
                        .with_label("temperatures incomplete")
                        .with_help("e.g. `beam(X, ends at (0, 800) mm, upper at (T_a, T_b), lower at (T_c, T_d), gap 200 mm, across z)`"),
                );
                return None;
            }
        };
        let s = sub(Scalar::Var(Var::Axis(axis)), Scalar::Num(ends[0]));
        let ramp = |v: &[Scalar; 2], k: f64, p: i32| {
            // v₀ sᵖ/p! + (v₁ − v₀) s^{p+1}/((p+1)! L), with k = 1/p!.
            let sp = (0..p).fold(Scalar::Num(1.0), |acc, _| mul(acc, s.clone()));
            let first = mul(mul(Scalar::Num(k), v[0].clone()), sp.clone());
            let slope = mul(
                Scalar::Num(k / (f64::from(p) + 1.0) / length),
                sub(v[1].clone(), v[0].clone()),
            );
            add(first, mul(slope, mul(sp, s.clone())))
        };
        let k = component.index() % 3;
        let (value, dim) = if component.is_rotation() {
            let Some((g_value, g)) = &gradient else {
                sink.push(beam_nothing(
                    span,
                    &self.current,
                    "a mean temperature only expands the beam",
                ));
                return None;
            };
            let n = cross(*g, u);
            if n[k].abs() < 1e-12 {
                sink.push(beam_nothing(span, &self.current, "a beam does not twist about its own axis, and bends about the axis normal to it and the gradient"));
                return None;
            }
            (
                mul(Scalar::Num(n[k]), ramp(g_value, 1.0, 1)),
                Dim::ANGLE * Dim::TEMPERATURE,
            )
        } else {
            let mut v: Option<Scalar> = None;
            if u[k].abs() > 1e-12 {
                v = Some(mul(Scalar::Num(u[k]), ramp(&mean, 1.0, 1)));
            }
            if let Some((g_value, g)) = &gradient {
                if g[k].abs() > 1e-12 {
                    let d = mul(Scalar::Num(-g[k]), ramp(g_value, 0.5, 2));
                    v = Some(match v {
                        Some(e) => add(e, d),
                        None => d,
                    });
                }
            }
            let Some(v) = v else {
                sink.push(beam_nothing(
                    span,
                    &self.current,
                    "the beam expands along its axis and deflects along the gradient",
                ));
                return None;
            };
            (v, Dim::LENGTH * Dim::TEMPERATURE)
        };
        Some(SymTerm::scalar(value, dim, span))
    }

    /// The two end temperatures of a `beam` option: known scalars, temperature rises.
    fn beam_pair(
        &mut self,
        opts: &mut Options<'_>,
        name: &str,
        span: Span,
        sink: &mut Sink,
    ) -> Option<Option<[Scalar; 2]>> {
        let Some(o) = opts.take(name) else {
            return Some(None);
        };
        let OptionValue::At {
            items, unit: None, ..
        } = &o.value
        else {
            sink.push(
                Diagnostic::error(
                    "E0105",
                    format!("`{name}` takes the temperatures at the two ends"),
                    o.value.span(),
                )
                .with_label("expected `at (T₀, T₁)`"),
            );
            return None;
        };
        let [a, b] = items.as_slice() else {
            sink.push(
                Diagnostic::error(
                    "E0105",
                    format!("`{name}` takes the temperatures at the two ends"),
                    o.value.span(),
                )
                .with_label(format!("{} values, expected 2", items.len())),
            );
            return None;
        };
        let _ = span;
        let mut out = Vec::with_capacity(2);
        for item in [a, b] {
            let terms = self.expand(item, sink)?;
            let t = self.collapse(terms, item.span, sink)?;
            if t.fitted {
                sink.push(
                    Diagnostic::error(
                        "E0307",
                        "a fitted factor cannot be a beam's temperature",
                        item.span,
                    )
                    .with_label("basis factor")
                    .with_note("the model must stay linear in the coefficients β"),
                );
                return None;
            }
            if t.dim != Dim::TEMPERATURE {
                sink.push(
                    Diagnostic::error(
                        "E0203",
                        format!(
                            "a beam's temperature must be a temperature, but this is {}",
                            t.dim.describe()
                        ),
                        item.span,
                    )
                    .with_label("expected a temperature rise"),
                );
                return None;
            }
            out.push(t.scale);
        }
        let b = out.pop()?;
        let a = out.pop()?;
        Some(Some([a, b]))
    }
}

fn beam_nothing(span: Span, target: &str, why: &str) -> Diagnostic {
    Diagnostic::error("E0310", format!("this `beam` gives no `{target}`"), span)
        .with_label("zero for this component")
        .with_note(why.to_string())
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn add(a: Scalar, b: Scalar) -> Scalar {
    Scalar::Add(Box::new(a), Box::new(b))
}

fn sub(a: Scalar, b: Scalar) -> Scalar {
    Scalar::Sub(Box::new(a), Box::new(b))
}

fn mul(a: Scalar, b: Scalar) -> Scalar {
    Scalar::Mul(Box::new(a), Box::new(b))
}

/// A lag while its cascade is checked, innermost stage first.
struct LagChain {
    lag: ir::Lag,
    dim: Dim,
    absolute: bool,
    /// Whether the first stage's time constant is set (an inner `lag` was read).
    staged: bool,
    from_span: Option<Span>,
}

/// At most this many terms in one expanded error model.
const MAX_TERMS: usize = 4096;

/// Families that bring coefficients.
const FAMILIES: [&str; 8] = [
    "linear",
    "poly",
    "spline",
    "straightness",
    "fourier",
    "periodic",
    "backlash",
    "direction",
];

/// Options each family accepts.
fn allowed_options(f: &str) -> &'static [&'static str] {
    match f {
        "poly" => &["degree"],
        "spline" => &["knots", "degree", "smooth", "no_once_per_rev"],
        "straightness" => &["knots", "degree", "smooth"],
        "fourier" => &["harmonics", "wavelength"],
        "periodic" => &["wavelength", "knots", "degree", "smooth", "phase"],
        "lag" => &["tau", "from"],
        "warmup" => &["tau"],
        "beam" => &["ends", "mean", "upper", "lower", "gap", "across"],
        _ => &[],
    }
}

/// The arguments of a family call: one positional variable, then named options.
struct Options<'a> {
    family: &'a str,
    span: Span,
    positional: Vec<&'a Expr>,
    options: Vec<&'a OptionArg>,
    flags: Vec<(String, Span)>,
    used: Vec<bool>,
    used_flags: Vec<bool>,
}

impl<'a> Options<'a> {
    fn new(family: &'a str, args: &'a [Arg], span: Span, sink: &mut Sink) -> Option<Self> {
        let mut positional = Vec::new();
        let mut options: Vec<&OptionArg> = Vec::new();
        let mut flags = Vec::new();
        let allowed = allowed_options(family);
        let mut ok = true;
        for a in args {
            match a {
                // A bare name after the variable is a flag such as `no_once_per_rev`.
                Arg::Positional(e) if !positional.is_empty() => match &e.kind {
                    ExprKind::Name(n) if allowed.contains(&n.as_str()) => {
                        flags.push((n.clone(), e.span))
                    }
                    _ => {
                        let mut d = Diagnostic::error(
                            "E0105",
                            format!("unexpected argument to `{family}`"),
                            e.span,
                        )
                        .with_label("expected an option such as `knots 4`");
                        if let ExprKind::Name(n) = &e.kind {
                            if let Some(s) = suggest(n, allowed.iter().copied()) {
                                d = d.with_help(format!("did you mean `{s}`?"));
                            }
                        }
                        sink.push(d);
                        ok = false;
                    }
                },
                Arg::Positional(e) => positional.push(e),
                Arg::Option(o) => {
                    if !allowed.contains(&o.name.node.as_str()) {
                        let mut d = Diagnostic::error(
                            "E0105",
                            format!("`{family}` has no option `{}`", o.name.node),
                            o.name.span,
                        )
                        .with_label("unknown option");
                        d = match suggest(&o.name.node, allowed.iter().copied()) {
                            Some(s) => d.with_help(format!("did you mean `{s}`?")),
                            None if allowed.is_empty() => {
                                d.with_note(format!("`{family}` takes no options"))
                            }
                            None => {
                                d.with_note(format!("`{family}` takes: {}", allowed.join(", ")))
                            }
                        };
                        sink.push(d);
                        ok = false;
                        continue;
                    }
                    if let Some(first) = options.iter().find(|p| p.name.node == o.name.node) {
                        sink.push(
                            Diagnostic::error(
                                "E0105",
                                format!("option `{}` is given twice", o.name.node),
                                o.name.span,
                            )
                            .with_label("second value")
                            .with_secondary(first.name.span, "first given here"),
                        );
                        ok = false;
                        continue;
                    }
                    if let Some(fit) = o.fit {
                        if !matches!(o.name.node.as_str(), "wavelength" | "tau") {
                            sink.push(
                                Diagnostic::error(
                                    "E0105",
                                    format!("`{}` cannot be fitted", o.name.node),
                                    fit,
                                )
                                .with_label("only `wavelength` and `tau` can be fitted"),
                            );
                            ok = false;
                        }
                    }
                    options.push(o);
                }
            }
        }
        if positional.len() != 1 {
            let at = positional.get(1).map(|e| e.span).unwrap_or(span);
            sink.push(
                Diagnostic::error(
                    "E0105",
                    format!("`{family}` takes exactly one variable"),
                    at,
                )
                .with_label(if positional.is_empty() {
                    "missing the variable"
                } else {
                    "extra argument"
                })
                .with_help(format!(
                    "e.g. `{family}(X{})`",
                    if allowed.is_empty() { "" } else { ", …" }
                )),
            );
            ok = false;
        }
        let (n_opt, n_flag) = (options.len(), flags.len());
        ok.then_some(Options {
            family,
            span,
            positional,
            options,
            flags,
            used: vec![false; n_opt],
            used_flags: vec![false; n_flag],
        })
    }

    /// The name of the family's variable; the checker resolves it.
    fn variable(&self, sink: &mut Sink) -> Option<(String, Span)> {
        let e = self.positional.first()?;
        match &e.kind {
            ExprKind::Name(n) => Some((n.clone(), e.span)),
            _ => {
                sink.push(
                    Diagnostic::error(
                        "E0305",
                        format!("the variable of `{}` must be a name", self.family),
                        e.span,
                    )
                    .with_label("expected an axis or an input")
                    .with_help("scale the term instead: `spline(X, knots 3) * (…)`"),
                );
                None
            }
        }
    }

    fn has(&self, name: &str) -> bool {
        self.options.iter().any(|o| o.name.node == name)
    }

    fn take(&mut self, name: &str) -> Option<&'a OptionArg> {
        let i = self.options.iter().position(|o| o.name.node == name)?;
        if let Some(u) = self.used.get_mut(i) {
            *u = true;
        }
        self.options.get(i).copied()
    }

    fn flag(&mut self, name: &str) -> bool {
        match self.flags.iter().position(|(n, _)| n == name) {
            Some(i) => {
                if let Some(u) = self.used_flags.get_mut(i) {
                    *u = true;
                }
                true
            }
            None => false,
        }
    }

    fn integer(&mut self, name: &str, lo: i64, hi: i64, sink: &mut Sink) -> Option<Option<i64>> {
        let Some(o) = self.take(name) else {
            return Some(None);
        };
        let value = match &o.value {
            OptionValue::Expr(Expr {
                kind: ExprKind::Quantity { value, unit: None },
                ..
            }) if value.fract() == 0.0 => *value as i64,
            other => {
                sink.push(
                    Diagnostic::error(
                        "E0105",
                        format!("`{name}` takes a whole number"),
                        other.span(),
                    )
                    .with_label("expected a whole number without unit"),
                );
                return None;
            }
        };
        if value < lo || value > hi {
            let code = if matches!(name, "degree" | "smooth") {
                "E0302"
            } else {
                "E0105"
            };
            sink.push(
                Diagnostic::error(code, format!("`{name} {value}` is out of bounds"), o.span)
                    .with_label(format!("must be between {lo} and {hi}")),
            );
            return None;
        }
        Some(Some(value))
    }

    /// `degree d` (default 2) and `smooth c` (default 1, or d − 1 for d = 1).
    fn degree_smooth(&mut self, sink: &mut Sink) -> Option<(u32, i32)> {
        let degree_opt = self
            .options
            .iter()
            .find(|o| o.name.node == "degree")
            .map(|o| o.span);
        let degree = self.integer("degree", 1, 5, sink)?.unwrap_or(2);
        let smooth_opt = self
            .options
            .iter()
            .find(|o| o.name.node == "smooth")
            .map(|o| o.span);
        let smooth = self
            .integer("smooth", -1, 5, sink)?
            .unwrap_or((degree - 1).min(1));
        if smooth >= degree {
            let mut d = Diagnostic::error(
                "E0302",
                format!("degree {degree} and smooth {smooth} contradict each other"),
                smooth_opt.or(degree_opt).unwrap_or(self.span),
            )
            .with_label(format!("continuity up to derivative {smooth} leaves no freedom at a knot of a degree-{degree} polynomial"))
            .with_note("pieces of degree d joined with continuity c < d; c = d would make one polynomial");
            if let (Some(s), Some(dg)) = (smooth_opt, degree_opt) {
                if s != dg {
                    d = d.with_secondary(dg, "degree given here");
                }
            }
            sink.push(d.with_help(format!(
                "use `smooth {}` or `degree {}`",
                degree - 1,
                smooth + 1
            )));
            return None;
        }
        Some((degree as u32, smooth as i32))
    }

    /// `knots N` (equally spaced) or `knots at (…) unit` (positions in the variable's units).
    fn knots(&mut self, range: [f64; 2], unit: &Unit, sink: &mut Sink) -> Option<Option<Vec<f64>>> {
        let Some(o) = self.take("knots") else {
            return Some(None);
        };
        match &o.value {
            OptionValue::At {
                items,
                unit: u,
                span,
            } => {
                // Knots of an absolute temperature are absolute temperatures, like its range;
                // the variable decides (its unit carries the offset), not the knots' unit text,
                // in which a lone `degC` always reads as absolute.
                let absolute = unit.offset != 0.0;
                let unit = match u {
                    Some(u) => {
                        let parsed = parse_unit(u, sink)?;
                        if absolute {
                            parsed.as_absolute()
                        } else {
                            parsed.as_difference()
                        }
                    }
                    None => unit.clone(),
                };
                let mut out = Vec::with_capacity(items.len());
                let mut last: Option<(f64, Span)> = None;
                for item in items {
                    let v = quantity_of(item, unit.dim, &unit, absolute, "a knot position", sink)?;
                    if !(v > range[0] && v < range[1]) {
                        sink.push(
                            Diagnostic::error("E0301", "knot outside the range", item.span)
                                .with_label(format!(
                                    "outside {} .. {} {}",
                                    fmt_num(unit.from_si(range[0])),
                                    fmt_num(unit.from_si(range[1])),
                                    unit.name
                                ))
                                .with_note("knots must lie strictly inside the variable's range"),
                        );
                        return None;
                    }
                    if let Some((prev, pspan)) = last {
                        if v <= prev {
                            sink.push(
                                Diagnostic::error(
                                    "E0301",
                                    "knots must be strictly increasing",
                                    item.span,
                                )
                                .with_label("not after the previous knot")
                                .with_secondary(pspan, "previous knot"),
                            );
                            return None;
                        }
                    }
                    last = Some((v, item.span));
                    out.push((v - range[0]) / (range[1] - range[0]));
                }
                if out.is_empty() {
                    sink.push(
                        Diagnostic::error("E0105", "empty knot list", *span).with_label("no knots"),
                    );
                    return None;
                }
                Some(Some(out))
            }
            OptionValue::Expr(Expr {
                kind: ExprKind::Quantity { value, unit: None },
                ..
            }) if value.fract() == 0.0 && *value >= 0.0 => {
                if *value > 50.0 {
                    sink.push(
                        Diagnostic::error("E0105", "at most 50 knots", o.span)
                            .with_label("too many knots"),
                    );
                    return None;
                }
                basis::equally_spaced_knots(*value as usize).ok().map(Some)
            }
            other => {
                sink.push(
                    Diagnostic::error(
                        "E0105",
                        "`knots` takes a count or `at (…)` positions",
                        other.span(),
                    )
                    .with_label("expected e.g. `knots 4` or `knots at (100, 250) mm`"),
                );
                None
            }
        }
    }

    fn harmonics(&mut self, sink: &mut Sink) -> Option<Vec<u32>> {
        let Some(o) = self.take("harmonics") else {
            sink.push(
                Diagnostic::error("E0105", "`fourier` needs `harmonics`", self.span)
                    .with_label("which harmonics?")
                    .with_help("e.g. `fourier(C, harmonics 2..4)` or `harmonics (2, 3, 5)`"),
            );
            return None;
        };
        let list: Vec<i64> = match &o.value {
            OptionValue::IntRange { lo, hi, .. } if lo <= hi && hi - lo <= 200 => {
                (*lo..=*hi).collect()
            }
            OptionValue::IntList { items, .. } => items.clone(),
            OptionValue::Expr(Expr {
                kind: ExprKind::Quantity { value, unit: None },
                ..
            }) if value.fract() == 0.0 => vec![*value as i64],
            other => {
                sink.push(
                    Diagnostic::error("E0306", "bad harmonics", other.span())
                        .with_label("expected e.g. `2..4` or `(2, 3, 5)`"),
                );
                return None;
            }
        };
        let mut out = Vec::with_capacity(list.len());
        for h in list {
            if !(1..=1000).contains(&h) {
                sink.push(
                    Diagnostic::error(
                        "E0306",
                        format!("harmonic {h} is not allowed"),
                        o.value.span(),
                    )
                    .with_label("harmonics are whole numbers from 1")
                    .with_note("the constant (harmonic 0) is `const`"),
                );
                return None;
            }
            if out.contains(&(h as u32)) {
                sink.push(
                    Diagnostic::error(
                        "E0306",
                        format!("harmonic {h} is listed twice"),
                        o.value.span(),
                    )
                    .with_label("duplicate harmonic"),
                );
                return None;
            }
            out.push(h as u32);
        }
        Some(out)
    }

    /// A quantity option of a dimension, in SI; `Some(None)` when absent.
    fn quantity(
        &mut self,
        name: &str,
        dim: Dim,
        default: &Unit,
        sink: &mut Sink,
    ) -> Option<Option<(f64, Span, bool)>> {
        let Some(o) = self.take(name) else {
            return Some(None);
        };
        let OptionValue::Expr(e) = &o.value else {
            sink.push(
                Diagnostic::error(
                    "E0105",
                    format!("`{name}` takes a quantity"),
                    o.value.span(),
                )
                .with_label(format!("expected {}", dim.describe())),
            );
            return None;
        };
        let what = format!("`{name}`");
        let c = constant(e, false, sink)?;
        let value = if c.bare {
            default.as_difference().to_si(c.value)
        } else if c.dim != dim {
            sink.push(
                Diagnostic::error(
                    "E0203",
                    format!(
                        "{what} must be {}, but this is {}",
                        dim.describe(),
                        c.dim.describe()
                    ),
                    e.span,
                )
                .with_label(format!("expected {}", dim.describe())),
            );
            return None;
        } else {
            c.value
        };
        Some(Some((value, e.span, o.fit.is_some())))
    }

    fn required_quantity(
        &mut self,
        name: &str,
        dim: Dim,
        default: &Unit,
        sink: &mut Sink,
    ) -> Option<(f64, Span, bool)> {
        match self.quantity(name, dim, default, sink)? {
            Some(q) => Some(q),
            None => {
                sink.push(
                    Diagnostic::error(
                        "E0105",
                        format!("`{}` needs `{name}`", self.family),
                        self.span,
                    )
                    .with_label(format!("missing `{name}`"))
                    .with_help(format!(
                        "e.g. `{name} {}` (add `fit` to estimate it)",
                        example_value(name)
                    )),
                );
                None
            }
        }
    }

    /// Every option must have been consumed by the family: anything left is unused.
    fn finish(&self, sink: &mut Sink) -> Option<()> {
        let mut ok = true;
        for (o, used) in self.options.iter().zip(&self.used) {
            if !used {
                sink.push(
                    Diagnostic::error(
                        "E0105",
                        format!("option `{}` does not apply here", o.name.node),
                        o.name.span,
                    )
                    .with_label("unused option"),
                );
                ok = false;
            }
        }
        for ((n, s), used) in self.flags.iter().zip(&self.used_flags) {
            if !used {
                sink.push(
                    Diagnostic::error("E0105", format!("`{n}` needs a value"), *s)
                        .with_label("missing value"),
                );
                ok = false;
            }
        }
        ok.then_some(())
    }
}

fn example_value(name: &str) -> &'static str {
    match name {
        "tau" => "30 min",
        "wavelength" => "25.4 mm",
        _ => "1",
    }
}

/// The largest time constant: 10¹⁰ s, some 300 years. A machine's thermal lags are minutes to
/// hours; beyond this the lag is a constant, and a start value like `1e300 min` only printed as
/// 300 digits.
const MAX_TAU: f64 = 1e10;

/// A time constant `tau` (SI) is positive and within [`MAX_TAU`], else an E0105 at `span`.
fn time_constant(tau: f64, span: Span, sink: &mut Sink) -> Option<()> {
    if tau > 0.0 && tau <= MAX_TAU {
        return Some(());
    }
    let (message, label) = if tau > 0.0 {
        (
            "the time constant is beyond 10¹⁰ s (some 300 years)",
            "too long",
        )
    } else {
        ("the time constant must be positive", "not positive")
    };
    sink.push(Diagnostic::error("E0105", message, span).with_label(label));
    None
}

fn absolute_temperature(span: Span) -> Diagnostic {
    Diagnostic::error(
        "E0204",
        "an absolute temperature cannot be used as a factor",
        span,
    )
    .with_label("absolute temperature")
    .with_note("errors follow temperature changes; an absolute temperature has an arbitrary zero")
    .with_help("subtract a reference temperature, e.g. `(T - 20 degC)`")
}

/// Whether every number folded into a scalar is finite.
fn finite(s: &Scalar) -> bool {
    match s {
        Scalar::Num(x) => x.is_finite(),
        Scalar::Var(_) => true,
        Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => finite(a),
        Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
            finite(a) && finite(b)
        }
    }
}

fn simplify_mul(a: Scalar, b: Scalar) -> Scalar {
    match (a, b) {
        (Scalar::Num(x), Scalar::Num(y)) => Scalar::Num(x * y),
        (Scalar::Num(x), other) | (other, Scalar::Num(x)) if x == 1.0 => other,
        (a, b) => Scalar::Mul(Box::new(a), Box::new(b)),
    }
}

/// The display unit of a dimension, built from the user's default units.
pub(crate) fn display_unit(dim: Dim, units: &ir::DisplayUnits) -> Unit {
    let bases = [
        (dim.length, &units.length),
        (dim.angle, &units.angle),
        (dim.time, &units.time),
        (dim.force, &units.force),
    ];
    // A difference of degC is a kelvin; `um/K` reads better than `um/degC` and means the same.
    let temperature = Unit::parse("K").unwrap_or_else(|_| units.temperature.as_difference());
    let mut out = Unit::dimensionless();
    for (exp, unit) in bases.into_iter().chain([(dim.temperature, &temperature)]) {
        if exp != 0 {
            out = out.mul(&unit.powi(i32::from(exp)));
        }
    }
    out
}

fn fmt_num(v: f64) -> String {
    let r = (v * 1e6).round() / 1e6;
    format!("{r}")
}

#[cfg(test)]
mod tests {
    use crate::basis::{Basis, Wavelength};
    use crate::ir::{Component, Machine, Var};

    fn machine(errors: &str) -> Machine {
        let src = format!(
            "machine m {{
                task position
                units {{ length mm, error um, tilt urad, time min }}
                input T : temperature rise
                axis X prismatic along x range 0 mm .. 500 mm
                tool chain {{ X moving  tool t at (0, 0, -100) mm }}
                errors {{ {errors} }}
            }}"
        );
        let out = crate::compile(&src);
        out.compiled
            .unwrap_or_else(|| panic!("{:?}", out.diagnostics))
            .machine
    }

    /// The wavelength parameter index of each fitted Fourier factor, by component.
    fn wavelengths(m: &Machine) -> Vec<(Component, usize)> {
        m.errors
            .iter()
            .flat_map(|e| e.terms.iter().map(move |t| (e.component, t)))
            .flat_map(|(c, t)| {
                t.factors.iter().filter_map(move |f| match &f.basis {
                    Basis::Fourier {
                        wavelength: Some(Wavelength::Fitted(nl)),
                        ..
                    } => Some((c, nl.index)),
                    _ => None,
                })
            })
            .collect()
    }

    #[test]
    fn several_targets_share_one_wavelength_and_keep_their_own_coefficients() {
        let m = machine(
            "X.tx = const
             X.tx, X.ry, X.rz += fourier(X, harmonics 1..2, wavelength fit 20 mm)",
        );
        assert_eq!(m.nonlinear.len(), 1, "{:?}", m.nonlinear);
        assert_eq!(m.nonlinear[0].name, "X.tx.wavelength");
        assert_eq!(
            wavelengths(&m),
            vec![(Component::Tx, 0), (Component::Ry, 0), (Component::Rz, 0)]
        );
        let names: Vec<&str> = m.coefficients.iter().map(|c| c.name.as_str()).collect();
        // `const`, then four harmonic columns per target.
        assert_eq!(names.len(), 1 + 3 * 4);
        assert_eq!(names[1..5], ["X.tx[1]", "X.tx[2]", "X.tx[3]", "X.tx[4]"]);
        assert_eq!(names[5..9], ["X.ry[0]", "X.ry[1]", "X.ry[2]", "X.ry[3]"]);
        assert_eq!(m.coefficients[2].unit.name, "um");
        assert_eq!(m.coefficients[6].unit.name, "urad");
        // Written apart, they are two parameters.
        let apart = machine(
            "X.tx += fourier(X, harmonics 1, wavelength fit 20 mm)
             X.ry += fourier(X, harmonics 1, wavelength fit 20 mm)",
        );
        assert_eq!(apart.nonlinear.len(), 2);
    }

    #[test]
    fn an_add_before_the_define_is_the_same_sum() {
        let after = machine("X.tx = const\n X.tx += linear(X)");
        let before = machine("X.tx += linear(X)\n X.tx = const");
        let terms = |m: &Machine| m.errors.iter().map(|e| e.terms.len()).sum::<usize>();
        assert_eq!(terms(&after), 2);
        assert_eq!(terms(&before), 2);
        assert_eq!(before.errors.len(), 1);
        // A second `=` is still two definitions, labelled at the first `=`, not at the `+=`.
        let src = "machine m {
                task position
                units { length mm, error um }
                axis X prismatic along x range 0 mm .. 500 mm
                tool chain { X moving  tool t }
                errors { X.tx += linear(X)
                         X.tx = const
                         X.tx = const }
            }";
        let out = crate::compile(src);
        let d: Vec<_> = out
            .diagnostics
            .iter()
            .filter(|d| d.code == "E0102")
            .collect();
        assert_eq!(d.len(), 1, "{:?}", out.diagnostics);
        let first = src.find("X.tx = const");
        assert!(
            d[0].labels.iter().any(|l| Some(l.span.start) == first),
            "{:?}",
            d[0]
        );
    }

    #[test]
    fn a_warm_up_is_a_lag_of_time_with_a_fitted_tau() {
        let m = machine("X.tx += warmup(time, tau fit 30 min) * linear(X)");
        assert_eq!(m.lags.len(), 1);
        assert!(m.lags[0].warmup && m.lags[0].from.is_none());
        assert_eq!(m.nonlinear.len(), 1);
        assert!(m.nonlinear[0].fitted);
        assert!((m.nonlinear[0].value - 1800.0).abs() < 1e-9);
        assert_eq!(m.nonlinear[0].name, "X.tx.tau");
    }

    #[test]
    fn several_targets_share_one_lag() {
        let m = machine("tool.tz, X.rx += lag(T, tau fit 30 min) * const");
        assert_eq!(m.lags.len(), 1);
        assert_eq!(m.nonlinear.len(), 1);
        assert_eq!(m.nonlinear[0].name, "tool.tz.tau");
        let lagged = m
            .errors
            .iter()
            .filter(|e| {
                e.terms
                    .iter()
                    .any(|t| t.scale == crate::ir::Scalar::Var(Var::Lag(0)))
            })
            .count();
        assert_eq!(lagged, 2);
    }

    fn heat(errors: &str) -> crate::lower::Output {
        let src = format!(
            "machine m {{
                task position
                units {{ length mm, error um, tilt urad, time min }}
                input T : temperature rise
                input T_abs : temperature absolute
                input S : speed
                input P : power [kW]
                axis X prismatic along x range 0 mm .. 500 mm
                tool chain {{ X moving  tool t at (0, 0, -100) mm }}
                errors {{ {errors} }}
            }}"
        );
        crate::compile(&src)
    }

    fn heat_machine(errors: &str) -> Machine {
        let out = heat(errors);
        out.compiled
            .unwrap_or_else(|| panic!("{:?}", out.diagnostics))
            .machine
    }

    fn heat_codes(errors: &str) -> Vec<String> {
        heat(errors)
            .diagnostics
            .iter()
            .filter(|d| d.severity == crate::diagnostic::Severity::Error)
            .map(|d| d.code.to_string())
            .collect()
    }

    #[test]
    fn a_power_of_a_heat_source_drives_a_lag() {
        let m = heat_machine("X.tx = lag(pow(S / 1000 rpm, 1.5), tau fit 40 min) * const");
        let l = &m.lags[0];
        assert_eq!(l.input, 2);
        assert!((l.source.reference - 1000.0 * std::f64::consts::TAU / 60.0).abs() < 1e-9);
        assert_eq!(l.source.power, 1.5);
        assert!(l.tau2.is_none());
        assert_eq!(m.coefficients[0].unit.name, "um", "a dimensionless drive");
        // 2000 rpm held: (2000/1000)^1.5.
        let u = 2000.0 * std::f64::consts::TAU / 60.0;
        assert!((l.steady(u) - 2f64.powf(1.5)).abs() < 1e-12);
        // An integer power keeps the unit: um per kW².
        let m = heat_machine("X.tx = lag(pow(P, 2), tau 5 min) * const");
        assert_eq!(m.lags[0].source.power, 2.0);
        assert_eq!(
            m.coefficients[0].unit.dim,
            crate::units::Dim::LENGTH / crate::units::Dim::POWER.powi(2)
        );
    }

    #[test]
    fn a_lag_of_a_lag_has_two_time_constants() {
        let m = heat_machine("X.tx = lag(lag(T, tau 10 min), tau fit 2 h) * const");
        assert_eq!(m.lags.len(), 1);
        let l = &m.lags[0];
        let inner = &m.nonlinear[l.tau.index];
        let outer = &m.nonlinear[l.tau2.map(|t| t.index).unwrap_or(usize::MAX)];
        assert_eq!(
            (inner.value, inner.fitted, inner.name.as_str()),
            (600.0, false, "X.tx.tau")
        );
        assert_eq!(
            (outer.value, outer.fitted, outer.name.as_str()),
            (7200.0, true, "X.tx.tau[1]")
        );
    }

    #[test]
    fn a_declared_initial_state_is_read_in_the_inputs_unit() {
        let m = heat_machine("X.tx = lag(S, tau 30 min, from 0 rpm) * const");
        assert_eq!(m.lags[0].from, Some(0.0));
        let m = heat_machine("X.tx = lag(lag(T, tau 3 min, from 2 K), tau 30 min) * const");
        assert_eq!(m.lags[0].from, Some(2.0));
        let m = heat_machine("X.tx = (lag(T_abs, tau 30 min, from 20 degC) - 20 degC) * const");
        assert!((m.lags[0].from.unwrap_or(0.0) - 293.15).abs() < 1e-9);
        let m = heat_machine("X.tx = lag(T, tau 30 min) * const");
        assert_eq!(m.lags[0].from, None);
    }

    #[test]
    fn heat_source_mistakes_are_located_errors() {
        assert_eq!(
            heat_codes("X.tx = pow(S / 1000 rpm, 1.5) * const"),
            ["E0308"]
        );
        assert_eq!(
            heat_codes("X.tx = lag(pow(S, 1.5), tau 1 min) * const"),
            ["E0308"]
        );
        assert_eq!(
            heat_codes("X.tx = lag(pow(S / 1000 rpm, 0), tau 1 min) * const"),
            ["E0308"]
        );
        assert_eq!(
            heat_codes("X.tx = lag(pow(S / 1000 rpm, 1.5 mm), tau 1 min) * const"),
            ["E0308"]
        );
        assert_eq!(
            heat_codes("X.tx = lag(pow(T_abs, 2), tau 1 min) * const"),
            ["E0204"]
        );
        assert_eq!(
            heat_codes("X.tx = lag(S / 0 rpm, tau 1 min) * const"),
            ["E0308"]
        );
        assert_eq!(
            heat_codes("X.tx = lag(lag(lag(T, tau 1 min), tau 2 min), tau 3 min) * const"),
            ["E0309"]
        );
        assert_eq!(
            heat_codes("X.tx = lag(lag(T, tau 1 min, from 0 K), tau 2 min, from 0 K) * const"),
            ["E0309"]
        );
        assert_eq!(
            heat_codes("X.tx = lag(S, tau 1 min, from 3 mm) * const"),
            ["E0203"]
        );
        assert_eq!(heat_codes("X.tx = lag(X, tau 1 min) * const"), ["E0305"]);
    }

    #[test]
    fn beam_mistakes_are_located_errors() {
        let ok = "ends at (0, 500) mm, upper at (T, T), lower at (0 K, 0 K), gap 100 mm, across z";
        assert!(heat_codes(&format!("X.tz = 11.5 um/m/K * beam(X, {ok})")).is_empty());
        assert!(heat_codes(&format!("X.ry = beam(X, {ok}) * const")).is_empty());
        // No torsion (thesis §3.4.3), no bending about the gradient's own direction.
        assert_eq!(
            heat_codes(&format!("X.rx = beam(X, {ok}) * const")),
            ["E0310"]
        );
        assert_eq!(
            heat_codes(&format!("X.rz = beam(X, {ok}) * const")),
            ["E0310"]
        );
        assert_eq!(
            heat_codes(&format!("X.tz, X.ry += beam(X, {ok}) * const")),
            ["E0310"]
        );
        assert_eq!(
            heat_codes("X.tz = beam(X, ends at (0, 500) mm, upper at (T, T), lower at (T, T), gap 1 mm, across x) * const"),
            ["E0310"]
        );
        assert_eq!(
            heat_codes("X.tz = beam(X, ends at (0, 500) mm, mean at (T, T)) * const"),
            ["E0310"]
        );
        assert_eq!(
            heat_codes("X.tx = beam(X, ends at (0, 500) mm, upper at (T, T)) * const"),
            ["E0105"]
        );
        assert_eq!(
            heat_codes("X.tx = beam(S, ends at (0, 500) mm, mean at (T, T)) * const"),
            ["E0305"]
        );
        assert_eq!(
            heat_codes("X.tx = beam(X, ends at (500, 0) mm, mean at (T, T)) * const"),
            ["E0304"]
        );
        assert_eq!(
            heat_codes("X.tx = beam(X, ends at (0, 500) mm, mean at (T, P)) * const"),
            ["E0203"]
        );
        assert_eq!(
            heat_codes("X.tx = beam(X, ends at (0, 500) mm, mean at (T, T_abs)) * const"),
            ["E0204"]
        );
        // A lagged temperature and an absolute one differenced are known temperature rises.
        assert!(heat_codes("X.tx = beam(X, ends at (0, 500) mm, mean at (lag(T, tau 5 min), T_abs - 20 degC)) * const").is_empty());
    }
}
