//! `kin check`: diagnostics, or a one-screen summary of the checked model.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::ExitCode;

use kin_compiler::ir::{FrameRef, JointKind, Machine, Task};
use kin_compiler::{compile, Compiled};
use kin_estimate::identify::Observe;
use serde::Serialize;

use crate::render;
use crate::Format;

/// What the identifiability analysis of `kin check` assumes is observed.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum ObserveArg {
    Position,
    Pose,
    Length,
}

impl From<ObserveArg> for Observe {
    fn from(o: ObserveArg) -> Observe {
        match o {
            ObserveArg::Position => Observe::Position,
            ObserveArg::Pose => Observe::Pose,
            ObserveArg::Length => Observe::Length,
        }
    }
}

pub fn run(
    path: &Path,
    format: Format,
    color: bool,
    identifiability: Option<(ObserveArg, bool)>,
    engine: kin_model::engine::Engine,
) -> ExitCode {
    let name = path.display().to_string();
    let Ok(crate::load::Source {
        text: source,
        diagnostics,
    }) = crate::load::source(path)
    else {
        return ExitCode::from(2);
    };
    // Text that is not UTF-8 is reported as it is, not compiled.
    let started = std::time::Instant::now();
    let mut out = if diagnostics.is_empty() {
        let out = compile(&source);
        crate::warnings::note(&crate::warnings::timed(
            &format!("compiled `{name}`"),
            started,
        ));
        out
    } else {
        kin_compiler::Output {
            compiled: None,
            diagnostics,
        }
    };
    // `// kin: allow` comments: their codes are allowed before anything is printed, and a code
    // kin does not have is warning W0803.
    let mut all = crate::warnings::directives(&source);
    all.append(&mut out.diagnostics);
    out.diagnostics = all;
    if let (Some(c), Some((observe, aligned))) = (&out.compiled, identifiability) {
        let found = kin_estimate::identify::checked(c, observe.into(), aligned, engine);
        if !found.is_empty() {
            out.diagnostics.extend(found);
            out.compiled = None;
        }
    }
    let ok = out.compiled.is_some();
    match format {
        Format::Human => {
            let mut stderr = std::io::stderr().lock();
            let shown = crate::warnings::shown(&name, &out.diagnostics);
            if render::human(&name, &source, &shown, color, &mut stderr).is_err() {
                return ExitCode::from(2);
            }
            if let Some(c) = &out.compiled {
                print!("{}", summary_text(&name, c));
            } else {
                let n = out.diagnostics.iter().filter(|d| d.is_error()).count();
                eprintln!("{name}: {n} error{}", if n == 1 { "" } else { "s" });
            }
        }
        Format::Json => {
            let kept = crate::warnings::kept(&out.diagnostics);
            let report = JsonReport {
                file: &name,
                ok,
                diagnostics: render::json_diagnostics(&name, &source, &kept),
                summary: out.compiled.as_ref().map(|c| Summary::of(&c.machine)),
            };
            match serde_json::to_string_pretty(&report) {
                Ok(s) => {
                    // This report is the run's document even when the model has errors.
                    crate::errors::document_printed();
                    println!("{s}");
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    return ExitCode::from(2);
                }
            }
        }
    }
    if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

#[derive(Serialize)]
struct JsonReport<'a> {
    file: &'a str,
    ok: bool,
    diagnostics: Vec<render::JsonDiagnostic<'a>>,
    summary: Option<Summary>,
}

/// What `kin check` reports about a clean model.
#[derive(Serialize)]
pub struct Summary {
    pub machine: String,
    pub task: &'static str,
    pub axes: Vec<String>,
    pub tool_chain: Vec<String>,
    pub workpiece_chain: Vec<String>,
    pub tools: Vec<String>,
    pub inputs: Vec<String>,
    pub error_models: usize,
    pub terms: usize,
    pub fixed_terms: usize,
    pub coefficients: usize,
    /// Coefficient count per unit.
    pub units: BTreeMap<String, usize>,
    pub nonlinear: Vec<String>,
}

impl Summary {
    pub fn of(m: &Machine) -> Summary {
        let element = |e: &kin_compiler::ir::Element| {
            let name = m
                .axes
                .get(e.axis)
                .map(|a| a.name.clone())
                .unwrap_or_default();
            format!(
                "{name} ({})",
                if e.frame == kin_compiler::ir::FrameKind::Moving {
                    "moving"
                } else {
                    "fixed"
                }
            )
        };
        let mut units = BTreeMap::new();
        for c in &m.coefficients {
            *units.entry(c.unit.name.clone()).or_insert(0) += 1;
        }
        let terms: usize = m.errors.iter().map(|e| e.terms.len()).sum();
        let fixed = m
            .errors
            .iter()
            .flat_map(|e| &e.terms)
            .filter(|t| t.coefficients == 0)
            .count();
        Summary {
            machine: m.name.clone(),
            task: match m.task {
                Task::Measure => "measure (indicated − true)",
                Task::Position => "position (actual − nominal)",
            },
            axes: m
                .axes
                .iter()
                .map(|a| {
                    let (kind, unit) = match a.kind {
                        JointKind::Prismatic => ("prismatic", &m.units.length),
                        JointKind::Revolute => ("revolute", &m.units.angle),
                    };
                    if a.continuous {
                        format!("{} {kind} continuous", a.name)
                    } else {
                        format!(
                            "{} {kind} {} .. {} {}",
                            a.name,
                            round(unit.from_si(a.range[0])),
                            round(unit.from_si(a.range[1])),
                            unit.name
                        )
                    }
                })
                .collect(),
            tool_chain: m.tool_chain.iter().map(element).collect(),
            workpiece_chain: m.workpiece_chain.iter().map(element).collect(),
            tools: m.tools.iter().map(|t| t.name.clone()).collect(),
            inputs: m
                .inputs
                .iter()
                .map(|i| format!("{} [{}]", i.name, i.unit.name))
                .collect(),
            error_models: m.errors.len(),
            terms,
            fixed_terms: fixed,
            coefficients: m.coefficients.len(),
            units,
            nonlinear: m
                .nonlinear
                .iter()
                .map(|p| {
                    format!(
                        "{} = {} {}{}",
                        p.name,
                        round(p.unit.from_si(p.value)),
                        p.unit.name,
                        if p.fitted { " (fitted)" } else { " (fixed)" }
                    )
                })
                .collect(),
        }
    }
}

fn round(v: f64) -> f64 {
    (v * 1e6).round() / 1e6
}

fn frame_name(m: &Machine, f: FrameRef) -> String {
    let axis = |list: &[kin_compiler::ir::Element], k: usize| {
        list.get(k)
            .and_then(|e| m.axes.get(e.axis))
            .map(|a| a.name.clone())
            .unwrap_or_default()
    };
    match f {
        FrameRef::Tool(k) => axis(&m.tool_chain, k),
        FrameRef::Workpiece(k) => axis(&m.workpiece_chain, k),
        FrameRef::ToolEnd(None) => "tool".into(),
        FrameRef::ToolEnd(Some(i)) => m.tools.get(i).map(|t| t.name.clone()).unwrap_or_default(),
        FrameRef::WorkpieceEnd => "workpiece".into(),
    }
}

pub fn summary_text(path: &str, c: &Compiled) -> String {
    let m = &c.machine;
    let s = Summary::of(m);
    let mut out = String::new();
    let mut line = |t: String| {
        out.push_str(&t);
        out.push('\n');
    };
    line(format!("{path}: machine `{}` checks clean", s.machine));
    line(format!("  task       {}", s.task));
    line(format!("  axes       {}", s.axes.join(", ")));
    line(format!(
        "  tool chain base → {} → tool [{}]",
        if s.tool_chain.is_empty() {
            "(none)".into()
        } else {
            s.tool_chain.join(" → ")
        },
        s.tools.join(", ")
    ));
    line(format!(
        "  workpiece  base → {} → workpiece",
        if s.workpiece_chain.is_empty() {
            "(none)".into()
        } else {
            s.workpiece_chain.join(" → ")
        }
    ));
    if !s.inputs.is_empty() {
        line(format!("  inputs     {}", s.inputs.join(", ")));
    }
    line(format!(
        "  errors     {} parametric error models, {} terms ({} fixed), {} coefficients",
        s.error_models, s.terms, s.fixed_terms, s.coefficients
    ));
    let units: Vec<String> = s.units.iter().map(|(u, n)| format!("{n} in {u}")).collect();
    if !units.is_empty() {
        line(format!("  units      {}", units.join(", ")));
    }
    let mut per_frame: Vec<(String, Vec<String>)> = Vec::new();
    for e in &m.errors {
        let name = frame_name(m, e.frame);
        let n: usize = e.terms.iter().map(|t| t.coefficients).sum();
        let item = format!("{}:{n}", e.component.name());
        match per_frame.iter_mut().find(|(f, _)| *f == name) {
            Some((_, items)) => items.push(item),
            None => per_frame.push((name, vec![item])),
        }
    }
    for (frame, items) in per_frame {
        line(format!("    {frame:<10} {}", items.join(" ")));
    }
    for p in &s.nonlinear {
        line(format!("  non-linear {p}"));
    }
    out
}
