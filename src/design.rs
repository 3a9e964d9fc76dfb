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
    /// Every group, combination and coefficient, not only the summary.
    pub detail: bool,
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

/// One error component as the plan sees it: the summary read first.
#[derive(Serialize)]
struct Component {
    /// kin's name (`X.tx`).
    error: String,
    /// The ISO 230-1 names of its coefficients (`EXX`; `-EC0Y` for a squareness constant).
    iso: Vec<String>,
    coefficients: usize,
    /// Coefficients the plan determines on their own.
    determined: usize,
    /// Coefficients no row of the plan sees, alone or with others.
    unseen: usize,
    /// Coefficients the plan sees only in combination with others, and the components those
    /// others belong to.
    traded: usize,
    with: Vec<String>,
}

#[derive(Serialize)]
struct Report {
    coefficients: usize,
    candidates: Option<usize>,
    /// Directions the candidates (or the plan) determine.
    rank: usize,
    condition: f64,
    components: Vec<Component>,
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
    detail: bool,
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
    print(&report, format, "the plan", detail);
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
            print(&report, a.format, "the plan", a.detail);
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
                components: components(m, &selection.reach),
                undetermined: undetermined(m, &selection.reach),
                terms: terms(m, &selection.reach),
                chosen: Some(selection.chosen.len()),
                exchanges: Some(selection.exchanges),
                figures,
            };
            print(&report, a.format, "the candidates", a.detail);
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
        components: components(m, &reach),
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

/// Per error component (in declaration order): how many of its coefficients the plan
/// determines, sees only with others (and whose), or does not see at all.
fn components(m: &Machine, e: &Estimability) -> Vec<Component> {
    let iso = m.iso_names();
    let component_of = |j: usize| {
        m.coefficients
            .get(j)
            .and_then(|c| c.name.rsplit_once('[').map(|(b, _)| b.to_string()))
            .unwrap_or_default()
    };
    let mut out: Vec<Component> = Vec::new();
    for j in 0..m.coefficients.len() {
        let name = component_of(j);
        // A component's coefficients are contiguous per line; a second line (`+=`) adds more.
        let at = match out.iter().position(|c| c.error == name) {
            Some(at) => at,
            None => {
                out.push(Component {
                    error: name.clone(),
                    iso: Vec::new(),
                    coefficients: 0,
                    determined: 0,
                    unseen: 0,
                    traded: 0,
                    with: Vec::new(),
                });
                out.len() - 1
            }
        };
        let Some(entry) = out.get_mut(at) else {
            continue;
        };
        entry.coefficients += 1;
        if let Some(Some(n)) = iso.get(j) {
            if !entry.iso.contains(n) {
                entry.iso.push(n.clone());
            }
        }
        if e.determined.get(j).copied().unwrap_or(false) {
            entry.determined += 1;
            continue;
        }
        match e.groups.iter().find(|g| g.members.contains(&j)) {
            Some(g) if !g.combinations.is_empty() => {
                entry.traded += 1;
                for &k in &g.members {
                    let other = component_of(k);
                    if other != name && !entry.with.contains(&other) {
                        entry.with.push(other);
                    }
                }
            }
            _ => entry.unseen += 1,
        }
    }
    out
}

/// A determined combination in physical terms: a rotation's weight beside a translation's is an
/// arm (`X.tx[0] + 265 mm × X.ry[0]`: the translation seen 265 mm off the axis line); weights
/// of like quantities are plain numbers. Weights are in SI per coefficient (largest 1).
fn physical(m: &Machine, members: &[usize], weights: &[f64]) -> String {
    use kin_compiler::units::Dim;
    let dim = |j: usize| m.coefficients.get(j).map(|c| c.unit.dim);
    // The reference: the first length coefficient with a weight, else the first with one.
    let lead = members
        .iter()
        .zip(weights)
        .filter(|(_, w)| **w != 0.0)
        .find(|(j, _)| dim(**j) == Some(Dim::LENGTH))
        .or_else(|| members.iter().zip(weights).find(|(_, w)| **w != 0.0));
    let Some((&lead_j, &lead_w)) = lead else {
        return String::new();
    };
    let length = &m.units.length;
    let mut parts: Vec<(f64, String)> = Vec::new();
    for (&j, &w) in members.iter().zip(weights) {
        if w == 0.0 {
            continue;
        }
        let name = m
            .coefficients
            .get(j)
            .map_or_else(|| format!("#{j}"), |c| c.name.clone());
        let r = w / lead_w;
        let text = if j == lead_j {
            name
        } else if dim(lead_j) == Some(Dim::LENGTH) && dim(j) == Some(Dim::ANGLE) {
            // m of translation per rad of rotation: an arm, in the machine's length unit.
            format!(
                "{} {} × {name}",
                kin_estimate::curves::num(length.from_si(r.abs()) - length.from_si(0.0), 3),
                length.name
            )
        } else if (r.abs() - 1.0).abs() < 5e-4 {
            // Equal weights to the precision shown: a plain sum or difference.
            name
        } else {
            format!("{} × {name}", kin_estimate::curves::num(r.abs(), 3))
        };
        parts.push((r, text));
    }
    let mut out = String::new();
    for (i, (r, text)) in parts.iter().enumerate() {
        if i > 0 {
            out.push_str(if *r < 0.0 { " - " } else { " + " });
        } else if *r < 0.0 {
            out.push('-');
        }
        out.push_str(text);
    }
    out
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
                    .map(|w| physical(m, &g.members, w))
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

/// Combinations listed in the summary before the rest is left to `--detail`.
const SHOWN_COMBINATIONS: usize = 12;

/// What a metrologist reads first: per error component, what the plan determines, sees only
/// with others, or does not see; the components it sees nothing of, per frame, on a line; the
/// combinations it determines of what it cannot separate, in physical terms.
fn summary(out: &mut String, r: &Report, detail: bool) {
    if r.rank == r.coefficients {
        let _ = writeln!(out, "  every coefficient is determined");
    }
    let named = |c: &Component| {
        if c.iso.is_empty() {
            c.error.clone()
        } else {
            format!("{} {}", c.error, c.iso.join("/"))
        }
    };
    let partial: Vec<&Component> = r
        .components
        .iter()
        .filter(|c| c.determined + c.traded > 0 && c.determined < c.coefficients)
        .collect();
    if !partial.is_empty() {
        let _ = writeln!(
            out,
            "  error components the plan does not wholly determine (ISO 230-1 names):"
        );
    }
    for c in &partial {
        let mut parts = vec![format!("{} determined", c.determined)];
        if c.traded > 0 {
            let with = if c.with.is_empty() {
                "each other".to_string()
            } else {
                c.with.join(", ")
            };
            parts.push(format!("{} only in combination with {with}", c.traded));
        }
        if c.unseen > 0 {
            parts.push(format!("{} not seen", c.unseen));
        }
        let _ = writeln!(
            out,
            "    {:<18} {} of {}: {}",
            named(c),
            c.determined,
            c.coefficients,
            parts[1..].join(", ")
        );
    }
    // Components of which nothing is seen, per frame, wrapped.
    let mut frames: Vec<(String, Vec<String>)> = Vec::new();
    for c in r
        .components
        .iter()
        .filter(|c| c.determined + c.traded == 0 && c.coefficients > 0)
    {
        let frame = c.error.split('.').next().unwrap_or("").to_string();
        let item = format!("{} ({})", named(c), c.coefficients);
        match frames.iter_mut().find(|(f, _)| *f == frame) {
            Some((_, items)) => items.push(item),
            None => frames.push((frame, vec![item])),
        }
    }
    if !frames.is_empty() {
        let _ = writeln!(
            out,
            "  not seen at all, or only through a placement fitted with them (coefficients):"
        );
        for (_, items) in &frames {
            let mut line = String::from("   ");
            for item in items {
                if line.len() + item.len() > 100 && line.len() > 3 {
                    let _ = writeln!(out, "{}", line.trim_end_matches(','));
                    line = String::from("   ");
                }
                line.push(' ');
                line.push_str(item);
                line.push(',');
            }
            let _ = writeln!(out, "{}", line.trim_end_matches(','));
        }
    }
    let combinations: Vec<&String> = r.undetermined.iter().flat_map(|u| &u.determined).collect();
    if !combinations.is_empty() {
        let shown = if detail {
            0
        } else {
            combinations.len().min(SHOWN_COMBINATIONS)
        };
        if shown > 0 {
            let _ = writeln!(
                out,
                "  determined only in combination ({} of {}):",
                shown,
                combinations.len()
            );
            for c in combinations.iter().take(shown) {
                let _ = writeln!(out, "    {c}");
            }
        }
    }
    if !detail && r.rank < r.coefficients {
        let _ = writeln!(
            out,
            "  (--detail: every group and combination, and each coefficient's σ per unit noise and VIF)"
        );
    }
}

fn print(r: &Report, format: Format, what: &str, detail: bool) {
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
            summary(&mut out, r, detail);
            if detail {
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
                            let _ = writeln!(
                                out,
                                "  {:<24} {:>14} {:>10}",
                                t.name, "undetermined", "-"
                            );
                        }
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
