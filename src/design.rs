//! `kin design`: choose a calibration plan from candidate measurements (D-optimality with the
//! artifacts' placements as nuisance parameters), or score a plan (spec/design.md).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use kin_compiler::ir::Machine;
use kin_runtime::design::{self, Estimability, Score};
use kin_runtime::fit::DataSet;
use kin_runtime::plan::{self, Plan};
use serde::Serialize;

use crate::load::{self, Failed};
use crate::Format;

/// What `--generate` writes.
pub struct Generate {
    /// Bar length, grid step of the first sphere (m) and angle step (rad).
    pub length: f64,
    pub step: f64,
    pub angle_step: f64,
    /// The two prismatic axes spanning the plane; the first two prismatic axes when empty.
    pub plane: Vec<String>,
}

/// At most this many candidates are generated: beyond it the exchange algorithm's memory
/// (one unit of p values each) and time grow past what a planning step should take.
const MAX_GENERATED: usize = 1_000_000;

pub struct DesignArgs {
    pub generate: Option<Generate>,
    pub machine: PathBuf,
    pub candidates: Option<PathBuf>,
    pub n: Option<usize>,
    pub output: Option<PathBuf>,
    pub evaluate: Option<PathBuf>,
    pub format: Format,
    pub engine: kin_runtime::engine::Engine,
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
    engine: kin_runtime::engine::Engine,
    color: bool,
) -> Result<(), Failed> {
    let compiled = load::machine(machine, None, color)?;
    let m = &compiled.machine;
    let mut engine = kin_runtime::engine::make(m, engine).map_err(|e| {
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
    let compiled = load::machine(&a.machine, None, a.color)?;
    let m = &compiled.machine;
    let mut engine = kin_runtime::engine::make(m, a.engine).map_err(|e| {
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
        let text = ballbar(m, g)?;
        let count = text.lines().count().saturating_sub(2);
        files_write(out, &text)?;
        eprintln!("wrote {count} ball-bar candidates to {}", out.display());
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

/// Ball-bar candidates in the plane of two prismatic axes: the first sphere on a grid of
/// `step` over both ranges, the bar at every multiple of `angle_step` in [0°, 360°), kept when
/// the second sphere is inside the ranges too. The other axes stay at the middle of their
/// ranges.
fn ballbar(m: &Machine, g: &Generate) -> Result<String, Failed> {
    use kin_compiler::ir::JointKind;
    let bad = |msg: String| {
        eprintln!("error: {msg}");
        Failed::USAGE
    };
    if !(g.length > 0.0 && g.step > 0.0 && g.angle_step > 0.0) {
        return Err(bad(
            "--length, --step and --angle-step must be above zero".into()
        ));
    }
    let prismatic: Vec<usize> = m
        .axes
        .iter()
        .enumerate()
        .filter(|(_, a)| a.kind == JointKind::Prismatic)
        .map(|(i, _)| i)
        .collect();
    let plane: Vec<usize> = if g.plane.is_empty() {
        prismatic.iter().take(2).copied().collect()
    } else {
        g.plane
            .iter()
            .map(|n| {
                prismatic
                    .iter()
                    .copied()
                    .find(|&i| m.axes.get(i).is_some_and(|a| &a.name == n))
                    .ok_or_else(|| bad(format!("`{n}` is not a prismatic axis of the machine")))
            })
            .collect::<Result<_, _>>()?
    };
    let (Some(&u), Some(&v), 2) = (plane.first(), plane.get(1), plane.len()) else {
        return Err(bad(
            "a ball-bar plane needs two prismatic axes (--plane X,Y)".into(),
        ));
    };
    let range = |i: usize| m.axes.get(i).map_or([0.0, 0.0], |a| a.range);
    let (ru, rv) = (range(u), range(v));
    let points = |r: [f64; 2]| ((r[1] - r[0]) / g.step).floor() as usize + 1;
    let angles = (std::f64::consts::TAU / g.angle_step).round().max(1.0) as usize;
    points(ru)
        .checked_mul(points(rv))
        .and_then(|n| n.checked_mul(angles))
        .filter(|&n| n <= MAX_GENERATED)
        .ok_or_else(|| {
            bad(format!(
                "the grid holds more than {MAX_GENERATED} candidates; use a larger --step or --angle-step"
            ))
        })?;
    let unit = |i: usize| match m.axes.get(i).map(|a| a.kind) {
        Some(JointKind::Revolute) => ("deg", 180.0 / std::f64::consts::PI),
        _ => ("mm", 1000.0),
    };
    let mut out = format!(
        "# ball-bar candidates: length {} mm, grid {} mm, angle step {} deg\n",
        round9(g.length * 1e3),
        round9(g.step * 1e3),
        round9(g.angle_step.to_degrees())
    );
    let mut header = Vec::new();
    for end in ["_1", "_2"] {
        for (i, a) in m.axes.iter().enumerate() {
            header.push(format!("{}{end}[{}]", a.name, unit(i).0));
        }
    }
    out.push_str(&header.join(","));
    out.push('\n');
    let eps = 1e-9;
    let inside = |x: f64, r: [f64; 2]| x >= r[0] - eps && x <= r[1] + eps;
    let mut row = Vec::with_capacity(2 * m.axes.len());
    for i in 0..points(ru) {
        for j in 0..points(rv) {
            let (x, y) = (ru[0] + g.step * i as f64, rv[0] + g.step * j as f64);
            for k in 0..angles {
                let (sn, cs) = (g.angle_step * k as f64).sin_cos();
                let (x2, y2) = (x + g.length * cs, y + g.length * sn);
                if !(inside(x2, ru) && inside(y2, rv)) {
                    continue;
                }
                row.clear();
                for (end_u, end_v) in [(x, y), (x2, y2)] {
                    for (a, axis) in m.axes.iter().enumerate() {
                        let value = if a == u {
                            end_u
                        } else if a == v {
                            end_v
                        } else {
                            0.5 * (axis.range[0] + axis.range[1])
                        };
                        row.push(format!("{}", round9(value * unit(a).1)));
                    }
                }
                out.push_str(&row.join(","));
                out.push('\n');
            }
        }
    }
    Ok(out)
}

/// Nine decimals: nanometres in mm, far below any machine's resolution, and no `1e-14` noise.
fn round9(v: f64) -> f64 {
    let r = (v * 1e9).round() / 1e9;
    if r == 0.0 {
        0.0
    } else {
        r
    }
}
