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
