//! From source text to the typed AST. pest recognises the text (grammar in `grammar/kin.pest`);
//! this module walks its pairs into `ast` nodes, keeping every span.
//!
//! pest stops at the first syntax error; [`parse_file_all`] looks for the next ones by blanking
//! out the bad statement and parsing again (`recover`). Semantic checks, which run on a
//! complete tree, report all they find.

use pest::error::{ErrorVariant, InputLocation};
use pest::iterators::Pair;
use pest::Parser as _;

use super::ast::*;
use crate::diagnostic::{Diagnostic, Span};

#[derive(pest_derive::Parser)]
#[grammar = "kin.pest"]
pub(crate) struct KinParser;

type P<'i> = Pair<'i, Rule>;
type Result<T> = std::result::Result<T, Diagnostic>;

/// Parse a machine description (optionally followed by a `params` block).
pub fn parse_file(source: &str) -> Result<File> {
    check_nesting(source)?;
    let mut pairs = KinParser::parse(Rule::file, source).map_err(|e| syntax_error(source, e))?;
    let file = next(&mut pairs.next().into_iter(), "file")?;
    let mut machine = None;
    let mut params = None;
    for pair in file.into_inner() {
        match pair.as_rule() {
            Rule::machine => machine = Some(build_machine(pair)?),
            Rule::params => params = Some(build_params(pair)?),
            _ => {}
        }
    }
    let machine = machine.ok_or_else(|| internal(Span::default(), "machine"))?;
    Ok(File { machine, params })
}

/// As [`parse_file`], but a file with syntax errors gives every one that
/// `recover` finds, not only the first.
pub fn parse_file_all(source: &str) -> std::result::Result<File, Vec<Diagnostic>> {
    parse_file(source).map_err(|first| {
        if first.code == "E0001" && check_nesting(source).is_ok() {
            super::recover::syntax_errors(source, first)
        } else {
            vec![first]
        }
    })
}

/// Parse a parameter file: one `params { … }` block.
pub fn parse_params(source: &str) -> Result<ParamsBlock> {
    check_nesting(source)?;
    let mut pairs =
        KinParser::parse(Rule::params_file, source).map_err(|e| syntax_error(source, e))?;
    let file = next(&mut pairs.next().into_iter(), "params file")?;
    for pair in file.into_inner() {
        if pair.as_rule() == Rule::params {
            return build_params(pair);
        }
    }
    Err(internal(Span::default(), "params"))
}

/// A pair's span without the whitespace pest's implicit skipping leaves at the end of a rule
/// whose last part is optional: labels end where the text does.
fn span(pair: &P) -> Span {
    let s = pair.as_span();
    let trimmed = pair.as_str().trim_end().len();
    Span::new(s.start(), s.start() + trimmed)
}

/// Deeper nesting than this is refused before parsing: the parser and the checker recurse once
/// per level, and no machine needs more.
const MAX_NESTING: usize = 64;

/// Refuses sources whose bracket nesting would exhaust the stack, with a located diagnostic.
fn check_nesting(source: &str) -> Result<()> {
    let mut depth = 0usize;
    let mut chars = source.char_indices().peekable();
    while let Some((i, c)) = chars.next() {
        match c {
            '/' if chars.peek().map(|(_, n)| *n) == Some('/') => {
                while chars.peek().is_some_and(|(_, n)| *n != '\n') {
                    chars.next();
                }
            }
            '/' if chars.peek().map(|(_, n)| *n) == Some('*') => {
                chars.next();
                let mut prev = ' ';
                for (_, n) in chars.by_ref() {
                    if prev == '*' && n == '/' {
                        break;
                    }
                    prev = n;
                }
            }
            '(' | '[' | '{' => {
                depth += 1;
                if depth > MAX_NESTING {
                    return Err(Diagnostic::error(
                        "E0001",
                        format!("syntax error: brackets nested more than {MAX_NESTING} deep"),
                        Span::new(i, i + 1),
                    )
                    .with_label("too deep")
                    .with_help("simplify the expression"));
                }
            }
            ')' | ']' | '}' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    Ok(())
}

/// A sum or product longer than this is refused: the syntax tree is built left-deep, so its
/// depth grows with the number of operands.
const MAX_OPERANDS: usize = 512;

/// The grammar guarantees the shapes walked below; reaching this means the walker and the
/// grammar disagree, which must still not panic on a user's file.
fn internal(span: Span, what: &str) -> Diagnostic {
    Diagnostic::error(
        "E0002",
        format!("internal error: unexpected syntax tree while reading {what}"),
        span,
    )
    .with_note("this is a bug in kin; please report it with the file that caused it")
}

fn next<'i>(it: &mut impl Iterator<Item = P<'i>>, what: &str) -> Result<P<'i>> {
    it.next().ok_or_else(|| internal(Span::default(), what))
}

fn name(pair: P) -> Name {
    Spanned {
        node: pair.as_str().to_string(),
        span: span(&pair),
    }
}

fn build_machine(pair: P) -> Result<Machine> {
    let sp = span(&pair);
    let mut inner = pair.into_inner();
    let _kw = next(&mut inner, "machine")?;
    let machine_name = name(next(&mut inner, "machine name")?);
    let mut items = Vec::new();
    for p in inner {
        let item = match p.as_rule() {
            Rule::task_decl => Item::Task(build_task(p)?),
            Rule::gravity_decl => Item::Gravity(build_gravity(p)?),
            Rule::units_decl => Item::Units(build_units(p)?),
            Rule::axis_decl => Item::Axis(Box::new(build_axis(p)?)),
            Rule::input_decl => Item::Input(build_input(p)?),
            Rule::chain_decl => Item::Chain(build_chain(p)?),
            Rule::errors_decl => Item::Errors(build_errors(p)?),
            _ => continue,
        };
        items.push(item);
    }
    Ok(Machine {
        name: machine_name,
        items,
        span: sp,
    })
}

fn build_gravity(pair: P) -> Result<Spanned<Direction>> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let _kw = next(&mut it, "gravity")?;
    let direction = build_direction(next(&mut it, "direction")?)?;
    Ok(Spanned {
        node: direction.node,
        span: sp,
    })
}

fn build_task(pair: P) -> Result<Spanned<TaskKind>> {
    let sp = span(&pair);
    let kind = pair
        .into_inner()
        .find(|p| p.as_rule() == Rule::task_kind)
        .ok_or_else(|| internal(sp, "task"))?;
    let node = if kind.as_str() == "measure" {
        TaskKind::Measure
    } else {
        TaskKind::Position
    };
    Ok(Spanned {
        node,
        span: span(&kind),
    })
}

fn build_units(pair: P) -> Result<UnitsDecl> {
    let sp = span(&pair);
    let mut bindings = Vec::new();
    for b in pair
        .into_inner()
        .filter(|p| p.as_rule() == Rule::unit_binding)
    {
        let mut it = b.into_inner();
        let quantity = name(next(&mut it, "unit binding")?);
        let unit = name(next(&mut it, "unit")?);
        bindings.push(UnitBinding { quantity, unit });
    }
    Ok(UnitsDecl { bindings, span: sp })
}

fn build_axis(pair: P) -> Result<AxisDecl> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let _kw = next(&mut it, "axis")?;
    let axis_name = name(next(&mut it, "axis name")?);
    let kind_pair = next(&mut it, "joint kind")?;
    let kind = Spanned {
        node: if kind_pair.as_str() == "prismatic" {
            JointKind::Prismatic
        } else {
            JointKind::Revolute
        },
        span: span(&kind_pair),
    };
    let direction = build_direction(next(&mut it, "direction")?)?;
    let range = match it.next() {
        Some(r) => Some(build_axis_range(r)?),
        None => None,
    };
    Ok(AxisDecl {
        name: axis_name,
        kind,
        direction,
        range,
        span: sp,
    })
}

fn build_direction(pair: P) -> Result<Spanned<Direction>> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let _word = next(&mut it, "direction")?;
    let target = next(&mut it, "direction")?;
    let node = match target.as_rule() {
        Rule::signed_axis => {
            let text = target.as_str();
            let negative = text.starts_with('-');
            let index = match text.trim_start_matches(['+', '-']) {
                "x" => 0,
                "y" => 1,
                _ => 2,
            };
            Direction::Coordinate { negative, index }
        }
        _ => Direction::Vector(Box::new(build_vector(target, None)?)),
    };
    Ok(Spanned { node, span: sp })
}

fn build_axis_range(pair: P) -> Result<Spanned<AxisRange>> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let first = next(&mut it, "axis range")?;
    let node = if first.as_rule() == Rule::kw_continuous {
        AxisRange::Continuous
    } else {
        let (lo, hi) = build_interval(next(&mut it, "interval")?)?;
        AxisRange::Interval(lo, hi)
    };
    Ok(Spanned { node, span: sp })
}

fn build_interval(pair: P) -> Result<(Expr, Expr)> {
    let mut it = pair.into_inner().filter(|p| p.as_rule() == Rule::quantity);
    let lo = build_quantity(next(&mut it, "interval")?)?;
    let hi = build_quantity(next(&mut it, "interval")?)?;
    Ok((lo, hi))
}

fn build_input(pair: P) -> Result<InputDecl> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let _kw = next(&mut it, "input")?;
    let input_name = name(next(&mut it, "input name")?);
    let _colon = next(&mut it, "input")?;
    let dimension = name(next(&mut it, "input dimension")?);
    let mut options = Vec::new();
    for opt in it {
        let osp = span(&opt);
        let mut parts = opt.into_inner();
        let first = next(&mut parts, "input option")?;
        options.push(match first.as_rule() {
            Rule::input_flag => InputOption::Flag(name(first)),
            Rule::kw_range => {
                let (lo, hi) = build_interval(next(&mut parts, "input range")?)?;
                InputOption::Range(lo, hi, osp)
            }
            Rule::unit_clause => {
                let unit = first
                    .into_inner()
                    .find(|p| p.as_rule() == Rule::unit)
                    .ok_or_else(|| internal(osp, "input unit"))?;
                InputOption::Unit(name(unit))
            }
            _ => return Err(internal(osp, "input option")),
        });
    }
    Ok(InputDecl {
        name: input_name,
        dimension,
        options,
        span: sp,
    })
}

fn build_chain(pair: P) -> Result<ChainDecl> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let kind_pair = next(&mut it, "chain kind")?;
    let kind = Spanned {
        node: if kind_pair.as_str() == "tool" {
            ChainKind::Tool
        } else {
            ChainKind::Workpiece
        },
        span: span(&kind_pair),
    };
    let mut items = Vec::new();
    for p in it {
        let isp = span(&p);
        match p.as_rule() {
            Rule::element => {
                let mut e = p.into_inner();
                let axis = name(next(&mut e, "chain element")?);
                let fk = next(&mut e, "frame kind")?;
                let frame = Spanned {
                    node: if fk.as_str() == "moving" {
                        FrameKind::Moving
                    } else {
                        FrameKind::Fixed
                    },
                    span: span(&fk),
                };
                let placement = build_placement(next(&mut e, "placement")?)?;
                items.push(ChainItem::Element {
                    axis,
                    frame,
                    placement,
                    span: isp,
                });
            }
            Rule::tool_item => {
                let mut e = p.into_inner();
                let _kw = next(&mut e, "tool")?;
                let tool_name = name(next(&mut e, "tool name")?);
                let placement = build_placement(next(&mut e, "placement")?)?;
                items.push(ChainItem::Tool {
                    name: tool_name,
                    placement,
                    span: isp,
                });
            }
            Rule::workpiece_item => {
                let mut e = p.into_inner();
                let _kw = next(&mut e, "workpiece")?;
                let placement = build_placement(next(&mut e, "placement")?)?;
                items.push(ChainItem::Workpiece {
                    placement,
                    span: isp,
                });
            }
            _ => {}
        }
    }
    Ok(ChainDecl {
        kind,
        items,
        span: sp,
    })
}

fn build_placement(pair: P) -> Result<Placement> {
    let mut placement = Placement::default();
    let mut pending = None;
    for p in pair.into_inner() {
        match p.as_rule() {
            Rule::kw_at | Rule::kw_rot => pending = Some(p.as_rule()),
            Rule::vector_q => {
                let mut vi = p.into_inner();
                let v = next(&mut vi, "vector")?;
                let unit = vi.next().map(name);
                let vector = build_vector(v, unit)?;
                if pending == Some(Rule::kw_rot) {
                    placement.rot = Some(vector);
                } else {
                    placement.at = Some(vector);
                }
            }
            _ => {}
        }
    }
    Ok(placement)
}

fn build_vector(pair: P, unit: Option<Name>) -> Result<Vector> {
    let mut sp = span(&pair);
    if let Some(u) = &unit {
        sp = sp.to(u.span);
    }
    let mut exprs = pair.into_inner().filter(|p| p.as_rule() == Rule::expr);
    let a = build_expr(next(&mut exprs, "vector")?)?;
    let b = build_expr(next(&mut exprs, "vector")?)?;
    let c = build_expr(next(&mut exprs, "vector")?)?;
    Ok(Vector {
        elems: [a, b, c],
        unit,
        span: sp,
    })
}

fn build_errors(pair: P) -> Result<ErrorsDecl> {
    let sp = span(&pair);
    let mut defs = Vec::new();
    for d in pair.into_inner().filter(|p| p.as_rule() == Rule::error_def) {
        let dsp = span(&d);
        let mut it = d.into_inner();
        let mut targets = Vec::new();
        let mut assign = next(&mut it, "error target")?;
        while assign.as_rule() != Rule::assign {
            if assign.as_rule() == Rule::target {
                let tsp = span(&assign);
                let mut names = assign
                    .into_inner()
                    .filter(|p| p.as_rule() == Rule::any_name);
                let frame = name(next(&mut names, "error target")?);
                let component = names.next().map(name);
                targets.push(Target {
                    frame,
                    component,
                    span: tsp,
                });
            }
            assign = next(&mut it, "assignment")?;
        }
        let value = build_expr(next(&mut it, "error model")?)?;
        defs.push(ErrorDef {
            targets,
            add: assign.as_str() == "+=",
            value,
            span: dsp,
        });
    }
    Ok(ErrorsDecl { defs, span: sp })
}

fn build_expr(pair: P) -> Result<Expr> {
    let sp = span(&pair);
    match pair.as_rule() {
        Rule::expr => {
            too_long(&pair, sp)?;
            let mut it = pair.into_inner();
            let mut acc = build_expr(next(&mut it, "expression")?)?;
            while let Some(op) = it.next() {
                let rhs = build_expr(next(&mut it, "expression")?)?;
                let op = if op.as_str() == "+" {
                    BinOp::Add
                } else {
                    BinOp::Sub
                };
                let s = acc.span.to(rhs.span);
                acc = Expr {
                    kind: ExprKind::Binary(op, Box::new(acc), Box::new(rhs)),
                    span: s,
                };
            }
            Ok(acc)
        }
        Rule::unary => {
            let mut it = pair.into_inner();
            let first = next(&mut it, "expression")?;
            if first.as_rule() == Rule::neg {
                let inner = build_expr(next(&mut it, "expression")?)?;
                Ok(Expr {
                    kind: ExprKind::Neg(Box::new(inner)),
                    span: sp,
                })
            } else {
                build_expr(first)
            }
        }
        Rule::product => {
            too_long(&pair, sp)?;
            let mut it = pair.into_inner();
            let mut acc = build_expr(next(&mut it, "expression")?)?;
            while let Some(op) = it.next() {
                let rhs = build_expr(next(&mut it, "expression")?)?;
                let op = if op.as_str() == "*" {
                    BinOp::Mul
                } else {
                    BinOp::Div
                };
                let s = acc.span.to(rhs.span);
                acc = Expr {
                    kind: ExprKind::Binary(op, Box::new(acc), Box::new(rhs)),
                    span: s,
                };
            }
            Ok(acc)
        }
        Rule::quantity | Rule::uquantity => build_quantity(pair),
        Rule::kw_const => Ok(Expr {
            kind: ExprKind::Const,
            span: sp,
        }),
        Rule::ident => Ok(Expr {
            kind: ExprKind::Name(pair.as_str().to_string()),
            span: sp,
        }),
        Rule::paren => {
            let inner = pair
                .into_inner()
                .find(|p| p.as_rule() == Rule::expr)
                .ok_or_else(|| internal(sp, "parenthesis"))?;
            let mut e = build_expr(inner)?;
            e.span = sp;
            Ok(e)
        }
        Rule::call => build_call(pair),
        _ => Err(internal(sp, "expression")),
    }
}

fn too_long(pair: &P, sp: Span) -> Result<()> {
    if pair.clone().into_inner().count() > 2 * MAX_OPERANDS {
        return Err(Diagnostic::error(
            "E0001",
            format!("syntax error: more than {MAX_OPERANDS} operands in one expression"),
            sp,
        )
        .with_label("too long")
        .with_help("split the model into several `+=` lines"));
    }
    Ok(())
}

fn build_quantity(pair: P) -> Result<Expr> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let num = next(&mut it, "number")?;
    let value = parse_number(&num)?;
    let unit = it.next().map(name);
    Ok(Expr {
        kind: ExprKind::Quantity { value, unit },
        span: sp,
    })
}

fn parse_number(pair: &P) -> Result<f64> {
    let text = pair.as_str();
    let value: f64 = text.parse().map_err(|_| {
        Diagnostic::error(
            "E0003",
            format!("`{text}` is not a valid number"),
            span(pair),
        )
        .with_label("not a number")
    })?;
    if !value.is_finite() {
        return Err(Diagnostic::error(
            "E0003",
            format!("`{text}` is too large to represent"),
            span(pair),
        )
        .with_label("out of range")
        .with_help("numbers must be finite double-precision values"));
    }
    Ok(value)
}

fn build_call(pair: P) -> Result<Expr> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let callee = name(next(&mut it, "call")?);
    let mut args = Vec::new();
    for p in it {
        match p.as_rule() {
            Rule::option => args.push(Arg::Option(build_option(p)?)),
            Rule::expr => args.push(Arg::Positional(build_expr(p)?)),
            _ => {}
        }
    }
    Ok(Expr {
        kind: ExprKind::Call { name: callee, args },
        span: sp,
    })
}

fn build_option(pair: P) -> Result<OptionArg> {
    let sp = span(&pair);
    let mut it = pair.into_inner();
    let opt_name = name(next(&mut it, "option")?);
    let mut fit = None;
    let mut value_pair = next(&mut it, "option value")?;
    if value_pair.as_rule() == Rule::kw_fit {
        fit = Some(span(&value_pair));
        value_pair = next(&mut it, "option value")?;
    }
    let vsp = span(&value_pair);
    let value = match value_pair.as_rule() {
        Rule::at_list => {
            let mut items = Vec::new();
            let mut unit = None;
            for p in value_pair.into_inner().flat_map(|p| match p.as_rule() {
                Rule::at_items => p.into_inner().collect::<Vec<_>>(),
                _ => vec![p],
            }) {
                match p.as_rule() {
                    Rule::expr => items.push(build_expr(p)?),
                    Rule::unit => unit = Some(name(p)),
                    _ => {}
                }
            }
            OptionValue::At {
                items,
                unit,
                span: vsp,
            }
        }
        Rule::int_range => {
            let mut ints = value_pair
                .into_inner()
                .filter(|p| p.as_rule() == Rule::integer);
            let lo = parse_int(&next(&mut ints, "range")?)?;
            let hi = parse_int(&next(&mut ints, "range")?)?;
            OptionValue::IntRange { lo, hi, span: vsp }
        }
        Rule::int_list => {
            let items = value_pair
                .into_inner()
                .filter(|p| p.as_rule() == Rule::integer)
                .map(|p| parse_int(&p))
                .collect::<Result<Vec<_>>>()?;
            OptionValue::IntList { items, span: vsp }
        }
        _ => OptionValue::Expr(build_expr(value_pair)?),
    };
    Ok(OptionArg {
        name: opt_name,
        fit,
        value,
        span: sp,
    })
}

fn parse_int(pair: &P) -> Result<i64> {
    pair.as_str().parse().map_err(|_| {
        Diagnostic::error(
            "E0003",
            format!("`{}` is not a valid integer", pair.as_str()),
            span(pair),
        )
        .with_label("not an integer")
    })
}

fn build_params(pair: P) -> Result<ParamsBlock> {
    let sp = span(&pair);
    let mut defs = Vec::new();
    for d in pair.into_inner().filter(|p| p.as_rule() == Rule::param_def) {
        let dsp = span(&d);
        let mut it = d.into_inner();
        let reference = next(&mut it, "parameter")?;
        let mut path = Vec::new();
        let mut index = None;
        for p in reference.into_inner() {
            match p.as_rule() {
                Rule::any_name => path.push(name(p)),
                Rule::integer => {
                    index = Some(Spanned {
                        node: parse_int(&p)?,
                        span: span(&p),
                    })
                }
                _ => {}
            }
        }
        let assign = next(&mut it, "assignment")?;
        let add = (assign.as_str() == "+=").then(|| span(&assign));
        let value_pair = next(&mut it, "parameter value")?;
        let inner = next(&mut value_pair.into_inner(), "parameter value")?;
        let vsp = span(&inner);
        let value = if inner.as_rule() == Rule::list_q {
            let mut values = Vec::new();
            let mut unit = None;
            for p in inner.into_inner().flat_map(|p| match p.as_rule() {
                Rule::list_items => p.into_inner().collect::<Vec<_>>(),
                _ => vec![p],
            }) {
                match p.as_rule() {
                    Rule::number => values.push(parse_number(&p)?),
                    Rule::unit => unit = Some(name(p)),
                    _ => {}
                }
            }
            ParamValue::List {
                values,
                unit,
                span: vsp,
            }
        } else {
            ParamValue::Scalar(build_quantity(inner)?)
        };
        defs.push(ParamDef {
            path,
            index,
            add,
            value,
            span: dsp,
        });
    }
    Ok(ParamsBlock { defs, span: sp })
}

/// How a rule is named in "expected …" messages.
fn describe(rule: Rule) -> Option<&'static str> {
    Some(match rule {
        Rule::lbrace => "`{`",
        Rule::rbrace => "`}`",
        Rule::lparen => "`(`",
        Rule::rparen => "`)`",
        Rule::lbrack => "`[`",
        Rule::rbrack => "`]`",
        Rule::comma => "`,`",
        Rule::colon => "`:`",
        Rule::dot => "`.`",
        Rule::dotdot => "`..`",
        Rule::assign => "`=` or `+=`",
        Rule::kw_machine => "`machine`",
        Rule::kw_params => "`params`",
        Rule::kw_task | Rule::task_decl => "`task`",
        Rule::kw_units | Rule::units_decl => "`units`",
        Rule::kw_gravity | Rule::gravity_decl => "`gravity`",
        Rule::kw_axis | Rule::axis_decl => "`axis`",
        Rule::kw_input | Rule::input_decl => "`input`",
        Rule::kw_tool | Rule::tool_item => "`tool`",
        Rule::kw_workpiece | Rule::workpiece_item => "`workpiece`",
        Rule::kw_chain => "`chain`",
        Rule::chain_decl | Rule::chain_kind => "a chain (`tool chain` or `workpiece chain`)",
        Rule::kw_errors | Rule::errors_decl => "`errors`",
        Rule::kw_range | Rule::axis_range => "`range` or `continuous`",
        Rule::kw_continuous => "`continuous`",
        Rule::kw_at => "`at`",
        Rule::kw_rot => "`rot`",
        Rule::kw_fit => "`fit`",
        Rule::kw_const => "`const`",
        Rule::task_kind => "`measure` or `position`",
        Rule::joint_kind => "`prismatic` or `revolute`",
        Rule::direction | Rule::dir_word => "`along` or `about`",
        Rule::signed_axis => "`x`, `y` or `z` (optionally signed)",
        Rule::vector | Rule::vector_q => "a vector `(a, b, c)`",
        Rule::frame_kind => "`moving` or `fixed`",
        Rule::input_flag => "`rise` or `absolute`",
        Rule::input_opt => "an input option (`rise`, `absolute`, `range`, `[unit]`)",
        Rule::unit | Rule::unit_name | Rule::unit_power => "a unit (`mm`, `urad`, `degC`, …)",
        Rule::unit_binding => "a unit binding such as `length mm`",
        Rule::unit_op => "`*` or `/`",
        Rule::ident | Rule::any_name => "a name",
        Rule::number | Rule::unsigned | Rule::quantity | Rule::uquantity => "a number",
        Rule::integer | Rule::int_range | Rule::int_list => "an integer",
        Rule::expr | Rule::unary | Rule::product | Rule::paren | Rule::call => "an expression",
        Rule::add_op => "`+` or `-`",
        Rule::mul_op => "`*` or `/`",
        Rule::neg => "`-`",
        Rule::option | Rule::at_list | Rule::at_items => "an option such as `knots 5`",
        Rule::error_def | Rule::target => "an error definition such as `X.tx = spline(X, knots 4)`",
        Rule::element => "a chain element such as `X moving`",
        Rule::param_def | Rule::param_ref => "a parameter such as `X.tx[0] = 1.5 um`",
        Rule::param_value | Rule::list_q | Rule::list_items => {
            "a value such as `1.5 um` or `[1, 2] um`"
        }
        Rule::machine => "`machine`",
        Rule::params => "`params`",
        Rule::interval => "a range such as `0 mm .. 600 mm`",
        Rule::placement => "`at` or `rot`",
        Rule::EOI => "end of file",
        _ => return None,
    })
}

pub(super) fn syntax_error(source: &str, err: pest::error::Error<Rule>) -> Diagnostic {
    let (start, end) = match err.location {
        InputLocation::Pos(p) => (p, p),
        InputLocation::Span((s, e)) => (s, e),
    };
    // Point at the offending token rather than an empty position.
    let end = if end > start {
        end
    } else {
        let rest = source.get(start..).unwrap_or("");
        let len = rest
            .char_indices()
            .take_while(|(_, c)| c.is_alphanumeric() || *c == '_')
            .last()
            .map(|(i, c)| i + c.len_utf8())
            .unwrap_or_else(|| rest.chars().next().map(char::len_utf8).unwrap_or(0));
        start + len
    };
    let found = match source.get(start..end).filter(|s| !s.is_empty()) {
        Some(s) if s.starts_with(['\n', '\r']) => "the end of the line".to_string(),
        Some(s) => format!("`{}`", s.escape_debug()),
        None => "end of file".to_string(),
    };
    // A word where a unit was expected is a misspelt unit far more often than anything else.
    let unit_expected = matches!(&err.variant, ErrorVariant::ParsingError { positives, .. } if positives.iter().any(|r| matches!(r, Rule::unit | Rule::unit_name | Rule::unit_power)));
    let word = source
        .get(start..end)
        .filter(|w| w.chars().all(|c| c.is_alphanumeric() || c == '_') && !w.is_empty());
    let unit_help = match (unit_expected, word) {
        (true, Some(w)) => {
            crate::diagnostic::suggest(w, super::UNIT_WORDS).map(|s| format!("did you mean `{s}`?"))
        }
        _ => None,
    };
    let message = match &err.variant {
        ErrorVariant::ParsingError { positives, .. } => {
            let mut expected: Vec<&str> = positives.iter().filter_map(|r| describe(*r)).collect();
            expected.sort_unstable();
            expected.dedup();
            match expected.as_slice() {
                [] => format!("unexpected {found}"),
                [one] => format!("expected {one}, found {found}"),
                many => {
                    let (last, rest) = many.split_last().unwrap_or((&"", &[]));
                    format!("expected {} or {last}, found {found}", rest.join(", "))
                }
            }
        }
        ErrorVariant::CustomError { message } => message.clone(),
    };
    let end = if source
        .get(start..end)
        .is_some_and(|s| s.starts_with(['\n', '\r']))
    {
        start
    } else {
        end
    };
    match (unit_help, word) {
        // Where a unit belongs, a word close to one is a misspelt unit, not a syntax error.
        (Some(help), Some(w)) => Diagnostic::error(
            "E0103",
            format!("unknown unit `{w}`"),
            Span::new(start, end),
        )
        .with_label("not a unit kin knows")
        .with_help(help),
        _ => Diagnostic::error(
            "E0001",
            format!("syntax error: {message}"),
            Span::new(start, end),
        )
        .with_label("unexpected here"),
    }
}
