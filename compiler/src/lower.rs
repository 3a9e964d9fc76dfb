//! Lowering: a parsed file to the IR, through resolution and checking.

use serde::Serialize;

use crate::check::check_errors;
use crate::diagnostic::{Diagnostic, Span};
use crate::ir;
use crate::params::bind;
use crate::resolve::{resolve, Sink};
use crate::syntax::{self, ast};

/// Where each part of the IR was declared, so later stages (identifiability, the fit) can point
/// at the user's text.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SourceMap {
    pub axes: Vec<Span>,
    pub inputs: Vec<Span>,
    pub tools: Vec<Span>,
    /// Per `Machine::errors` entry: the target of its first definition.
    pub errors: Vec<Span>,
    /// Per coefficient: the term that introduced it.
    pub coefficients: Vec<Span>,
    pub nonlinear: Vec<Span>,
}

/// A compiled machine and the map back to its source.
#[derive(Debug, Clone)]
pub struct Compiled {
    pub machine: ir::Machine,
    pub map: SourceMap,
}

/// The result of compiling: the machine when there was no error, and every diagnostic
/// (warnings included) either way.
#[derive(Debug, Clone)]
pub struct Output {
    pub compiled: Option<Compiled>,
    pub diagnostics: Vec<Diagnostic>,
}

/// Parses, resolves, checks and lowers a `.kin` source.
pub fn compile(source: &str) -> Output {
    match syntax::parse_file_all(source) {
        Ok(file) => lower(&file),
        Err(diagnostics) => Output {
            compiled: None,
            diagnostics,
        },
    }
}

fn lower(file: &ast::File) -> Output {
    let mut sink = Sink::default();
    let st = resolve(&file.machine, &mut sink);
    let decls: Vec<&ast::ErrorsDecl> = file
        .machine
        .items
        .iter()
        .filter_map(|i| match i {
            ast::Item::Errors(e) => Some(e),
            _ => None,
        })
        .collect();
    let models = check_errors(&decls, &st, &mut sink);
    for (i, used) in models.used_inputs.iter().enumerate() {
        if !used {
            if let (Some(input), Some(span)) = (st.inputs.get(i), st.input_spans.get(i)) {
                sink.push(
                    Diagnostic::warning(
                        "W0101",
                        format!("input `{}` is never used", input.name),
                        *span,
                    )
                    .with_label("declared here")
                    .with_note("measurement files may still carry its column"),
                );
            }
        }
    }
    let mut machine = ir::Machine {
        name: st.name,
        task: st.task,
        gravity: st.gravity,
        axes: st.axes,
        inputs: st.inputs,
        lags: models.lags,
        nonlinear: models.nonlinear,
        tool_chain: st.tool_chain,
        workpiece_chain: st.workpiece_chain,
        tools: st.tools,
        workpiece: st.workpiece,
        errors: models.errors,
        coefficients: models.coefficients,
        beta: Vec::new(),
        units: st.units,
    };
    if let Some(params) = &file.params {
        sink.diagnostics.extend(bind(&mut machine, params));
    }
    let declared = file
        .machine
        .items
        .iter()
        .any(|i| matches!(i, ast::Item::Gravity(_)));
    if !declared {
        ambiguous_gravity(&machine, &st.axis_spans, &mut sink);
    }
    let map = SourceMap {
        axes: st.axis_spans,
        inputs: st.input_spans,
        tools: st.tool_spans,
        errors: models.error_spans,
        coefficients: models.coefficient_spans,
        nonlinear: models.nonlinear_spans,
    };
    let compiled = (!sink.has_errors()).then_some(Compiled { machine, map });
    Output {
        compiled,
        diagnostics: sink.diagnostics,
    }
}

/// The sine of the angle from gravity beyond which a full-turn axis is called horizontal (30°).
const HORIZONTAL: f64 = 0.5;

/// Without a `gravity` item, gravity is −z of the base. That is ambiguous where the structure
/// suggests another vertical: a rotary axis that turns through a full revolution (a rotary
/// table, a spindle, a positioner's plate), whose direction is fixed in the base, and that −z
/// makes horizontal. On a horizontal machining centre or a lathe (ISO 841 puts Z along the
/// spindle) such an axis is vertical or the base's z is not up, and the gravity forms the
/// diagnosis proposes would be the wrong ones; a positioner that really tilts says so by
/// declaring `gravity along -z`. Warning `W0102`, at the axis' declaration.
fn ambiguous_gravity(m: &ir::Machine, spans: &[Span], sink: &mut Sink) {
    for chain in [&m.tool_chain, &m.workpiece_chain] {
        for (j, e) in chain.iter().enumerate() {
            let Some(axis) = m.axes.get(e.axis) else {
                continue;
            };
            let revolute = |k: usize| {
                m.axes
                    .get(k)
                    .is_some_and(|a| a.kind == ir::JointKind::Revolute)
            };
            let full_turn =
                axis.continuous || axis.range[1] - axis.range[0] >= std::f64::consts::TAU - 1e-9;
            // Carried by another rotary axis: its direction in the base changes with that
            // axis, and no single direction of it is "the" vertical.
            let carried = chain.iter().take(j).any(|b| revolute(b.axis));
            if !revolute(e.axis) || !full_turn || carried {
                continue;
            }
            let (Some(u), Some(span)) = (m.home_direction(e.axis), spans.get(e.axis)) else {
                continue;
            };
            let c = [
                u[1] * m.gravity[2] - u[2] * m.gravity[1],
                u[2] * m.gravity[0] - u[0] * m.gravity[2],
                u[0] * m.gravity[1] - u[1] * m.gravity[0],
            ];
            if (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() <= HORIZONTAL {
                continue;
            }
            let down = [-u[0], -u[1], -u[2]];
            sink.push(
                Diagnostic::warning(
                    "W0102",
                    format!(
                        "`{}` turns through a full revolution about a horizontal direction",
                        axis.name
                    ),
                    *span,
                )
                .with_label("horizontal if gravity acts along -z of the base")
                .with_note(
                    "the model has no `gravity` item, so gravity is taken along -z of the base; a rotary table or spindle usually turns about the vertical (on a horizontal machining centre or a lathe, ISO 841 puts Z along the spindle), and the deflections under gravity `kin diagnose` proposes depend on it",
                )
                .with_help(format!(
                    "declare the direction gravity acts in: `gravity along {}` if `{}` is vertical, `gravity along -z` if it really tilts",
                    signed_axis(down),
                    axis.name
                )),
            );
        }
    }
}

/// `-y`, `+x`, … for a unit vector along a coordinate axis; `(a, b, c)` otherwise.
fn signed_axis(v: [f64; 3]) -> String {
    for (i, name) in ["x", "y", "z"].iter().enumerate() {
        if (v[i].abs() - 1.0).abs() < 1e-9 {
            return format!("{}{name}", if v[i] < 0.0 { "-" } else { "+" });
        }
    }
    // Six decimals, without trailing zeros or a negative zero.
    let r = |x: f64| (x * 1e6).round() / 1e6 + 0.0;
    format!("({}, {}, {})", r(v[0]), r(v[1]), r(v[2]))
}
