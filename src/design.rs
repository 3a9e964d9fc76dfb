//! `kin design`: choose a calibration plan from candidate measurements (D-optimality with the
//! artifacts' placements as nuisance parameters), or score a plan (spec/design.md).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use kin_compiler::ir::Machine;
use kin_estimate::design::{self, Estimability, Score};
use kin_estimate::fit::DataSet;
use kin_estimate::generate::GenerateError;
use kin_estimate::plan::{self, Plan};
use serde::Serialize;

use crate::load::{self, Failed};
use crate::Format;

pub struct DesignArgs {
    pub generate: Option<kin_estimate::generate::Generate>,
    pub machine: PathBuf,
    pub candidates: Option<PathBuf>,
    pub n: Option<usize>,
    pub output: Option<PathBuf>,
    pub evaluate: Option<PathBuf>,
    pub format: Format,
    pub engine: kin_model::engine::Engine,
    pub ignore: crate::args::DataOptions,
    pub color: bool,
}

#[derive(Serialize)]
struct Figures {
    observations: usize,
    det_root: f64,
    average_prediction_variance: f64,
    maximum_prediction_variance: f64,
    /// What the prediction variances are taken over.
    over: String,
}

#[derive(Serialize)]
struct Undetermined {
    /// The coefficients no subset of the plan (or candidates) separates.
    terms: Vec<String>,
    /// The combinations of them that are determined, as text (`a + b`).
    determined: Vec<String>,
}

/// One coefficient as the plan determines it.
#[derive(Serialize)]
struct Term {
    name: String,
    determined: bool,
    /// Standard deviation per unit noise (SI units of the coefficient per unit of the rows).
    sigma_per_unit_noise: Option<f64>,
    /// Variance inflation against an orthogonal plan with the same column lengths.
    vif: Option<f64>,
}

#[derive(Serialize)]
struct Report {
    coefficients: usize,
    candidates: Option<usize>,
    /// Directions the candidates (or the plan) determine.
    rank: usize,
    condition: f64,
    undetermined: Vec<Undetermined>,
    terms: Vec<Term>,
    chosen: Option<usize>,
    exchanges: Option<usize>,
    figures: Option<Figures>,
}

/// `kin check MACHINE --plan FILE…`: what the plan made of `files` (together) determines.
pub fn check_plan(
    machine: &Path,
    files: &[PathBuf],
    format: Format,
    engine: kin_model::engine::Engine,
    color: bool,
) -> Result<(), Failed> {
    let compiled = load::machine(machine, None, color)?;
    let m = &compiled.machine;
    let mut engine = kin_model::engine::make(m, engine).map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let mut sets = Vec::with_capacity(files.len());
    for path in files {
        sets.push(DataSet {
            path: path.clone(),
            observations: load::observations(path, &compiled, true, &Default::default())?,
        });
    }
    plan::as_planned(&mut sets);
    let planned = plan::units(m, engine.as_mut(), &sets).map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let report = assess(m, &planned, None);
    print(&report, format, "the plan");
    Ok(())
}

pub fn run(a: DesignArgs) -> Result<(), Failed> {
    // An output that cannot be written is refused before the model is even read (spec/cli.md).
    if let Some(out) = &a.output {
        let mut inputs: Vec<&Path> = vec![&a.machine];
        inputs.extend(a.candidates.as_deref());
        crate::files::check(out, &inputs)?;
    }
    let compiled = load::machine(&a.machine, None, a.color)?;
    let m = &compiled.machine;
    let mut engine = kin_model::engine::make(m, a.engine).map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let mut units_of = |path: &Path| -> Result<Plan, Failed> {
        let observations = load::observations(path, &compiled, true, &a.ignore)?;
        let mut files = vec![DataSet {
            path: path.to_path_buf(),
            observations,
        }];
        plan::as_planned(&mut files);
        plan::units(m, engine.as_mut(), &files).map_err(|e| {
            eprintln!("error: {e}");
            Failed::INPUT
        })
    };
    let p = m.coefficients.len();
    if let Some(g) = &a.generate {
        let Some(out) = &a.output else {
            eprintln!("error: --generate needs -o CANDIDATES.csv");
            return Err(Failed::USAGE);
        };
        crate::files::check(out, &[&a.machine])?;
        let candidates = kin_estimate::generate::generate(m, g).map_err(|e| {
            eprintln!("error: {e}");
            match e {
                GenerateError::Kinematics(_) => Failed::INPUT,
                _ => Failed::USAGE,
            }
        })?;
        files_write(out, &candidates.text)?;
        eprintln!(
            "wrote {} candidate rows to {}",
            candidates.rows,
            out.display()
        );
        return Ok(());
    }
    match (&a.candidates, &a.evaluate) {
        (None, None) => {
            eprintln!("error: give --candidates FILE (with -n and -o) or --evaluate PLAN");
            Err(Failed::USAGE)
        }
        (candidates, Some(plan_path)) => {
            let planned = units_of(plan_path)?;
            let over = match candidates {
                Some(c) => Some((units_of(c)?, c.clone())),
                None => None,
            };
            let report = assess(
                m,
                &planned,
                over.as_ref().map(|(c, path)| (c, path.as_path())),
            );
            print(&report, a.format, "the plan");
            Ok(())
        }
        (Some(cands), None) => {
            let (Some(n), Some(out)) = (a.n, &a.output) else {
                eprintln!("error: choosing a plan needs -n N and -o PLAN.csv");
                return Err(Failed::USAGE);
            };
            crate::files::check(out, &[&a.machine, cands])?;
            let c = units_of(cands)?;
            let bar = ProgressBar::new_spinner();
            crate::warnings::hush(&bar);
            bar.set_style(
                ProgressStyle::with_template("{msg} {spinner} {pos} steps")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            bar.set_message("exchanging");
            let selection = design::select(&c.units, n, p, || bar.inc(1));
            bar.finish_and_clear();
            let selection = selection.map_err(|e| {
                eprintln!("error: {e}");
                Failed::INPUT
            })?;
            let text = load::read_text(cands)?;
            files_write(out, &plan_text(&text, &c, &selection.chosen))?;
            let figures = figures(
                &c,
                &selection.chosen,
                &c.units,
                p,
                &selection.reach,
                format!("the rows of {}", cands.display()),
            );
            let report = Report {
                coefficients: p,
                candidates: Some(c.units.len()),
                rank: selection.reach.rank,
                condition: selection.reach.condition,
                undetermined: undetermined(m, &selection.reach),
                terms: terms(m, &selection.reach),
                chosen: Some(selection.chosen.len()),
                exchanges: Some(selection.exchanges),
                figures,
            };
            print(&report, a.format, "the candidates");
            Ok(())
        }
    }
}

/// The Table 4.1 figures of `chosen`, or None (with the reason on stderr) when the plan does not
/// determine every coefficient.
fn figures(
    plan: &Plan,
    chosen: &[usize],
    over: &[design::Unit],
    p: usize,
    reach: &Estimability,
    over_text: String,
) -> Option<Figures> {
    if reach.rank < p {
        eprintln!(
            "note: {} of {p} coefficient directions cannot be determined; the figures are not computed",
            p - reach.rank
        );
        return None;
    }
    match design::score(&plan.units, chosen, over, p) {
        Ok(Score {
            observations,
            det_root,
            average,
            maximum,
            ..
        }) => Some(Figures {
            observations,
            det_root,
            average_prediction_variance: average,
            maximum_prediction_variance: maximum,
            over: over_text,
        }),
        Err(e) => {
            eprintln!("note: {e}; the figures are not computed");
            None
        }
    }
}

/// What `planned` determines, and its figures with prediction variances over `over` (the
/// candidates and their path) or over its own rows.
fn assess(m: &Machine, planned: &Plan, over: Option<(&Plan, &Path)>) -> Report {
    let p = m.coefficients.len();
    let all: Vec<usize> = (0..planned.units.len()).collect();
    let reach = design::estimability(&design::information(&planned.units, &all, p));
    let (set, over_text) = match over {
        Some((c, path)) => (&c.units, format!("the rows of {}", path.display())),
        None => (&planned.units, "the plan's own rows".to_string()),
    };
    let figures = figures(planned, &all, set, p, &reach, over_text);
    Report {
        coefficients: p,
        candidates: over.map(|(c, _)| c.units.len()),
        rank: reach.rank,
        condition: reach.condition,
        undetermined: undetermined(m, &reach),
        terms: terms(m, &reach),
        chosen: None,
        exchanges: None,
        figures,
    }
}

fn terms(m: &Machine, e: &Estimability) -> Vec<Term> {
    m.coefficients
        .iter()
        .enumerate()
        .map(|(j, c)| Term {
            name: c.name.clone(),
            determined: e.determined.get(j).copied().unwrap_or(false),
            sigma_per_unit_noise: e.sigma.get(j).copied().flatten(),
            vif: e.vif.get(j).copied().flatten(),
        })
        .collect()
}

fn undetermined(m: &Machine, e: &Estimability) -> Vec<Undetermined> {
    let name = |j: usize| {
        m.coefficients
            .get(j)
            .map_or_else(|| format!("#{j}"), |c| c.name.clone())
    };
    e.groups
        .iter()
        .map(|g| {
            let names: Vec<String> = g.members.iter().map(|&j| name(j)).collect();
            Undetermined {
                terms: names.clone(),
                determined: g
                    .combinations
                    .iter()
                    .map(|w| design::combination_text(&names, w))
                    .collect(),
            }
        })
        .collect()
}

/// The plan file: the candidate file's comments and header, then the chosen units' lines (a
/// unit chosen twice, a replicated measurement, appears twice).
fn plan_text(text: &str, c: &Plan, chosen: &[usize]) -> String {
    let lines: Vec<&str> = text.lines().collect();
    let first_data = c
        .lines
        .iter()
        .flat_map(|(_, l)| l.iter().copied())
        .min()
        .unwrap_or(1);
    let mut out = String::new();
    for l in lines.iter().take(first_data.saturating_sub(1)) {
        out.push_str(l);
        out.push('\n');
    }
    for &u in chosen {
        if let Some((_, ls)) = c.lines.get(u) {
            for &l in ls {
                if let Some(t) = l.checked_sub(1).and_then(|i| lines.get(i)) {
                    out.push_str(t);
                    out.push('\n');
                }
            }
        }
    }
    out
}

fn files_write(path: &Path, text: &str) -> Result<(), Failed> {
    crate::files::write(path, text.as_bytes())
}

fn print(r: &Report, format: Format, what: &str) {
    match format {
        Format::Json => match serde_json::to_string_pretty(r) {
            Ok(s) => println!("{s}"),
            Err(e) => eprintln!("error: {e}"),
        },
        Format::Human => {
            let mut out = String::new();
            if let Some(c) = r.candidates {
                let _ = writeln!(out, "candidates: {c} units");
            }
            let _ = writeln!(
                out,
                "{what} determine{} {} of {} coefficient directions (condition number {:.3e})",
                if what == "the plan" { "s" } else { "" },
                r.rank,
                r.coefficients,
                r.condition
            );
            for u in &r.undetermined {
                if u.determined.is_empty() {
                    let _ = writeln!(out, "  not determined at all: {}", u.terms.join(", "));
                } else {
                    let _ = writeln!(
                        out,
                        "  cannot separate {}; determined: {}",
                        u.terms.join(", "),
                        u.determined.join("; ")
                    );
                }
            }
            let _ = writeln!(
                out,
                "  {:<24} {:>14} {:>10}",
                "coefficient", "σ / unit noise", "VIF"
            );
            for t in &r.terms {
                match (t.sigma_per_unit_noise, t.vif) {
                    (Some(s), Some(v)) => {
                        let _ = writeln!(out, "  {:<24} {s:>14.4e} {v:>10.3}", t.name);
                    }
                    _ => {
                        let _ =
                            writeln!(out, "  {:<24} {:>14} {:>10}", t.name, "undetermined", "-");
                    }
                }
            }
            if let (Some(n), Some(x)) = (r.chosen, r.exchanges) {
                let _ = writeln!(out, "chose {n} units ({x} exchanges)");
            }
            if let Some(f) = &r.figures {
                let _ = writeln!(out, "observations          {}", f.observations);
                let _ = writeln!(
                    out,
                    "det^(1/p) of n·Cov    {:.4e}  (unit noise, SI)",
                    f.det_root
                );
                let _ = writeln!(
                    out,
                    "prediction variance   average {:.3}, maximum {:.3}  (n·xᵀCov x over {})",
                    f.average_prediction_variance, f.maximum_prediction_variance, f.over
                );
            }
            print!("{out}");
        }
    }
}
