//! Testing the candidate library against the data, and locating where the model fails.

use std::collections::HashMap;

use kin_compiler::ir::{JointKind, Machine};
use kin_compiler::{compile, Compiled, Diagnostic};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};
use thiserror::Error;

use super::library::{self, Available, Proposal};
use super::{Bin, Diagnosis, Finding, Region, Spectrum};
use crate::data::Observations;
use crate::fit::report::{component_name, model_hash};
use crate::fit::{self, DataSet, FitResult, Layout, StreamingQr, LENGTH};

#[derive(Debug, Error)]
pub enum DiagnoseError {
    #[error(transparent)]
    Fit(#[from] fit::FitError),
    #[error(transparent)]
    Design(#[from] fit::DesignError),
    #[error("the model with the candidate terms does not compile: {0}")]
    Candidates(String),
    #[error(transparent)]
    Eval(#[from] crate::interp::EvalError),
    #[error(transparent)]
    Engine(#[from] crate::engine::EngineError),
}

#[derive(Debug, Clone)]
pub struct Settings {
    /// Family-wise significance level over all candidates (Holm–Bonferroni).
    pub alpha: f64,
    /// Time constants scanned for thermal lags, s.
    pub taus: Vec<f64>,
    /// Bins per variable for locating failures.
    pub bins: usize,
    /// What evaluates the model with all its candidates.
    pub engine: crate::engine::Engine,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            alpha: 0.01,
            taus: vec![600.0, 1800.0, 5400.0],
            bins: 8,
            engine: crate::engine::Engine::default(),
        }
    }
}

/// Diagnoses a fitted model: `base` is the fit of `compiled` (from `source`) to `files`.
pub fn diagnose(
    compiled: &Compiled,
    source: &str,
    files: &[DataSet],
    base: &FitResult,
    options: &fit::Options,
    settings: &Settings,
) -> Result<Diagnosis, DiagnoseError> {
    let m = &compiled.machine;
    let s = m.units.error.scale;
    let rows = positions(m, files, base);
    let spectra = spectra(m, &rows, base.sigma);
    let peaks: Vec<(usize, f64)> = spectra
        .iter()
        .filter(|sp| sp.peak_false_alarm < 0.01)
        .filter_map(|sp| {
            let a = m.axes.iter().position(|ax| ax.name == sp.variable)?;
            let (k, _) = sp
                .power
                .iter()
                .enumerate()
                .max_by(|x, y| x.1.total_cmp(y.1))?;
            let unit = &m.units.length;
            Some((a, unit.to_si(*sp.wavelengths.get(k)?) - unit.to_si(0.0)))
        })
        .collect();
    let available = available(m, files);
    let proposals = library::propose(m, &available, &peaks, &settings.taus);
    let findings = test_candidates(compiled, source, files, base, options, &proposals, settings)?;
    let (regions, bins) = regions(m, &rows, base, settings);
    let all: Vec<f64> = base.residuals.iter().map(|r| r.residual / s).collect();
    Ok(Diagnosis {
        machine: m.name.clone(),
        model_hash: model_hash(source),
        sigma: base.sigma / s,
        rms: crate::fit::report::rms(&all),
        error_unit: m.units.error.name.clone(),
        alpha: settings.alpha,
        regions,
        bins,
        spectra,
        findings,
    })
}

fn available(m: &Machine, files: &[DataSet]) -> Available {
    let all = |f: &dyn Fn(&DataSet) -> bool| !files.is_empty() && files.iter().all(f);
    Available {
        directions: (0..m.axes.len())
            .map(|a| {
                all(&|d: &DataSet| match &d.observations {
                    Observations::Points(p) => p.pose.dir.get(a).is_some_and(|c| c.is_some()),
                    Observations::Lengths(l) => l
                        .poses
                        .iter()
                        .all(|p| p.dir.get(a).is_some_and(|c| c.is_some())),
                })
            })
            .collect(),
        inputs: (0..m.inputs.len())
            .map(|i| {
                all(&|d: &DataSet| {
                    d.observations
                        .rows()
                        .inputs
                        .get(i)
                        .is_some_and(|c| c.as_ref().is_some_and(|v| v.iter().all(|x| !x.is_nan())))
                })
            })
            .collect(),
        time: all(&|d: &DataSet| d.observations.rows().time.is_some()),
    }
}

/// One residual with the state variables it was observed at (display units).
struct Located {
    component: u8,
    residual: f64,
    leverage: f64,
    /// Axis positions, then inputs, then time (NaN where unknown).
    values: Vec<f64>,
    /// Direction of motion per axis (±1, NaN where not given).
    dirs: Vec<f64>,
}

/// Names and units of the located variables, in `Located::values` order.
fn variables(m: &Machine) -> Vec<(String, String)> {
    let mut v: Vec<(String, String)> = m
        .axes
        .iter()
        .map(|a| {
            (
                a.name.clone(),
                if a.kind == JointKind::Prismatic {
                    m.units.length.name.clone()
                } else {
                    m.units.angle.name.clone()
                },
            )
        })
        .collect();
    v.extend(
        m.inputs
            .iter()
            .map(|i| (i.name.clone(), i.unit.name.clone())),
    );
    v.push(("time".into(), m.units.time.name.clone()));
    v
}

fn positions(m: &Machine, files: &[DataSet], base: &FitResult) -> Vec<Located> {
    let s = m.units.error.scale;
    let index: Vec<HashMap<usize, usize>> = files
        .iter()
        .map(|f| {
            f.observations
                .rows()
                .line
                .iter()
                .enumerate()
                .map(|(r, &l)| (l, r))
                .collect()
        })
        .collect();
    let axis_unit = |a: usize| match m.axes.get(a).map(|x| x.kind) {
        Some(JointKind::Revolute) => &m.units.angle,
        _ => &m.units.length,
    };
    base.residuals
        .iter()
        .filter_map(|r| {
            let f = files.get(r.meta.file as usize)?;
            let row = *index
                .get(r.meta.file as usize)?
                .get(&(r.meta.line as usize))?;
            let rows = f.observations.rows();
            let mut values: Vec<f64> = match &f.observations {
                Observations::Points(p) => p
                    .pose
                    .axes
                    .iter()
                    .enumerate()
                    .map(|(a, c)| {
                        c.get(row)
                            .map(|v| axis_unit(a).from_si(*v))
                            .unwrap_or(f64::NAN)
                    })
                    .collect(),
                // A length is located at the middle of its two ends.
                Observations::Lengths(l) => (0..m.axes.len())
                    .map(|a| {
                        let end = |e: usize| {
                            l.poses[e]
                                .axes
                                .get(a)
                                .and_then(|c| c.get(row))
                                .copied()
                                .unwrap_or(f64::NAN)
                        };
                        axis_unit(a).from_si((end(0) + end(1)) / 2.0)
                    })
                    .collect(),
            };
            for (i, input) in m.inputs.iter().enumerate() {
                values.push(
                    rows.inputs
                        .get(i)
                        .and_then(|c| c.as_ref())
                        .and_then(|c| c.get(row))
                        .map(|v| input.unit.from_si(*v))
                        .unwrap_or(f64::NAN),
                );
            }
            values.push(
                rows.time
                    .as_ref()
                    .and_then(|t| t.get(row))
                    .map(|t| m.units.time.from_si(*t))
                    .unwrap_or(f64::NAN),
            );
            let dirs = match &f.observations {
                Observations::Points(p) => (0..m.axes.len())
                    .map(|a| {
                        p.pose
                            .dir
                            .get(a)
                            .and_then(|c| c.as_ref())
                            .and_then(|c| c.get(row))
                            .copied()
                            .unwrap_or(f64::NAN)
                    })
                    .collect(),
                Observations::Lengths(_) => vec![f64::NAN; m.axes.len()],
            };
            Some(Located {
                component: r.meta.component,
                residual: r.residual / s,
                leverage: r.leverage,
                values,
                dirs,
            })
        })
        .collect()
}

/// Lomb–Scargle periodogram (Scargle 1982) of the residuals along each prismatic axis, per
/// translation component: for non-uniform sampling, which is what real measurement plans are.
fn spectra(m: &Machine, rows: &[Located], _sigma: f64) -> Vec<Spectrum> {
    let mut out = Vec::new();
    for (a, axis) in m.axes.iter().enumerate() {
        if axis.kind != JointKind::Prismatic {
            continue;
        }
        let unit = &m.units.length;
        let range = unit.from_si(axis.range[1]) - unit.from_si(axis.range[0]);
        for c in [0u8, 1, 2, LENGTH] {
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.component == c)
                .filter_map(|r| Some((*r.values.get(a)?, r.residual)))
                .filter(|(x, _)| x.is_finite())
                .collect();
            if pts.len() < 30 {
                continue;
            }
            let n = pts.len() as f64;
            let mean = pts.iter().map(|p| p.1).sum::<f64>() / n;
            let var = pts.iter().map(|p| (p.1 - mean).powi(2)).sum::<f64>() / (n - 1.0);
            if var <= 0.0 {
                continue;
            }
            // Wavelengths from two thirds of the range down to about four samples per period.
            let longest = range / 1.5;
            let shortest = (4.0 * range / n).max(range / 2000.0);
            let count = 600;
            let mut wavelengths = Vec::with_capacity(count);
            let mut trig: Vec<(f64, f64)> = Vec::with_capacity(pts.len());
            let mut power = Vec::with_capacity(count);
            for k in 0..count {
                let lambda = longest * (shortest / longest).powf(k as f64 / (count - 1) as f64);
                let w = std::f64::consts::TAU / lambda;
                // One sincos per point: the double angle gives τ's sums, the angle difference
                // the projections (four trigonometric calls per point otherwise).
                trig.clear();
                trig.extend(pts.iter().map(|(x, _)| libm::sincos(w * x)));
                let (s2, c2): (f64, f64) = trig.iter().fold((0.0, 0.0), |(s, c), (sn, cs)| {
                    (s + 2.0 * sn * cs, c + cs * cs - sn * sn)
                });
                let (st, ct) = libm::sincos(0.5 * libm::atan2(s2, c2));
                let (mut yc, mut ys, mut cc, mut ss) = (0.0, 0.0, 0.0, 0.0);
                for ((_, y), (sn, cs)) in pts.iter().zip(&trig) {
                    // sin(w(x − τ)) and cos(w(x − τ)) with wτ = atan2(s2, c2)/2.
                    let (sn, cs) = (sn * ct - cs * st, cs * ct + sn * st);
                    yc += (y - mean) * cs;
                    ys += (y - mean) * sn;
                    cc += cs * cs;
                    ss += sn * sn;
                }
                let p = if cc > 0.0 && ss > 0.0 {
                    (yc * yc / cc + ys * ys / ss) / (2.0 * var)
                } else {
                    0.0
                };
                wavelengths.push(lambda);
                power.push(p);
            }
            let peak = power.iter().copied().fold(0.0, f64::max);
            // Independent frequencies ≈ the number of periods the grid spans over the range.
            let independent = (range / shortest).max(1.0);
            let fap = 1.0 - (1.0 - (-peak).exp()).powf(independent);
            out.push(Spectrum {
                component: component_name(c).to_string(),
                variable: axis.name.clone(),
                unit: unit.name.clone(),
                wavelengths,
                power,
                peak_false_alarm: fap.clamp(0.0, 1.0),
            });
        }
    }
    out
}

/// Per proposal (its index), the super-model's coefficient columns of each of its terms.
type TermColumns = Vec<(usize, Vec<Vec<usize>>)>;

/// Compiles the model with every candidate appended, dropping candidates that do not compile.
/// Returns the super-model and the columns of the kept proposals.
fn super_model(
    compiled: &Compiled,
    source: &str,
    proposals: &[Proposal],
) -> Result<(Compiled, TermColumns), DiagnoseError> {
    let file = kin_compiler::syntax::parse_file(source)
        .map_err(|d| DiagnoseError::Candidates(d.message))?;
    // Candidate lines go just before the closing brace of the last `errors` block, or into a
    // new block before the machine's closing brace.
    let (at, open, close) = match file.machine.errors_close() {
        Some(at) => (at, String::new(), String::new()),
        None => (
            file.machine.span.end.saturating_sub(1),
            "errors {\n".to_string(),
            "}\n".to_string(),
        ),
    };
    // Each term written on its own (harmonics unmerged), so that its coefficients can be told
    // from its neighbours' by their spans.
    type Ranges = Vec<(usize, Vec<std::ops::Range<usize>>)>;
    let build = |chosen: &[usize]| -> (String, Ranges) {
        let mut text = String::from(source.get(..at).unwrap_or(""));
        text.push('\n');
        text.push_str(&open);
        let mut ranges = Vec::new();
        for &k in chosen {
            let p = &proposals[k];
            text.push_str(&p.candidate.target);
            text.push_str(" += ");
            let mut terms = Vec::new();
            for (i, t) in p.terms.iter().enumerate() {
                if i > 0 {
                    text.push_str(" + ");
                }
                let start = text.len();
                text.push_str(&t.test);
                terms.push(start..text.len());
            }
            ranges.push((k, terms));
            text.push('\n');
        }
        text.push_str(&close);
        text.push_str(source.get(at..).unwrap_or(""));
        (text, ranges)
    };
    let compiles = |chosen: &[usize]| -> bool {
        compile(&build(chosen).0)
            .diagnostics
            .iter()
            .all(|d: &Diagnostic| !d.is_error())
    };
    let all: Vec<usize> = (0..proposals.len()).collect();
    let chosen: Vec<usize> = if compiles(&all) {
        all
    } else {
        (0..proposals.len()).filter(|&k| compiles(&[k])).collect()
    };
    let (text, ranges) = build(&chosen);
    let out = compile(&text);
    let Some(mut sup) = out.compiled else {
        return Err(DiagnoseError::Candidates(
            out.diagnostics
                .first()
                .map(|d| d.message.clone())
                .unwrap_or_default(),
        ));
    };
    // The base model's non-linear parameters keep their fitted values.
    for p in &mut sup.machine.nonlinear {
        if let Some(b) = compiled.machine.nonlinear.iter().find(|q| q.name == p.name) {
            p.value = b.value;
        }
    }
    let columns = ranges
        .into_iter()
        .map(|(k, terms)| {
            let cols = terms
                .iter()
                .map(|range| {
                    sup.map
                        .coefficients
                        .iter()
                        .enumerate()
                        .filter(|(_, s)| s.start >= range.start && s.end <= range.end)
                        .map(|(j, _)| j)
                        .collect()
                })
                .collect();
            (k, cols)
        })
        .collect();
    Ok((sup, columns))
}

/// A column that keeps no more than this fraction of its norm once the columns before it are
/// projected out adds no direction: the threshold at which the identifiability analysis names
/// a dependent column (E0601, spec/semantics.md), so that a term kept in a candidate's line is
/// one `kin check` and `kin fit` will also see as new.
const DEPENDENT: f64 = 1e-6;

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Removes from `v` its components along the orthonormal `basis` (Gram–Schmidt, twice, so the
/// result is orthogonal to working precision).
fn project_out(v: &mut [f64], basis: &[Vec<f64>]) {
    for _ in 0..2 {
        for b in basis {
            let d = dot(v, b);
            v.iter_mut().zip(b).for_each(|(x, y)| *x -= d * y);
        }
    }
}

/// Appends `v` (already orthogonal to `basis`) to the basis if it keeps a direction of its own
/// against the norm `norm` of its column of X.
fn extend(basis: &mut Vec<Vec<f64>>, mut v: Vec<f64>, norm: f64) -> bool {
    let n = dot(&v, &v).sqrt();
    // NaN counts as dependent.
    let own = n > DEPENDENT * norm.max(f64::MIN_POSITIVE);
    if !own {
        return false;
    }
    v.iter_mut().for_each(|x| *x /= n);
    basis.push(v);
    true
}

fn test_candidates(
    compiled: &Compiled,
    source: &str,
    files: &[DataSet],
    base: &FitResult,
    options: &fit::Options,
    proposals: &[Proposal],
    settings: &Settings,
) -> Result<Vec<Finding>, DiagnoseError> {
    if proposals.is_empty() {
        return Ok(Vec::new());
    }
    let m = &compiled.machine;
    let (sup, columns) = super_model(compiled, source, proposals)?;
    let values: Vec<f64> = match &base.nonlinear {
        Some(n) => sup
            .machine
            .nonlinear
            .iter()
            .map(|p| {
                m.nonlinear
                    .iter()
                    .position(|q| q.name == p.name)
                    .and_then(|i| n.values.get(i).copied())
                    .unwrap_or(p.value)
            })
            .collect(),
        None => sup.machine.nonlinear.iter().map(|p| p.value).collect(),
    };
    let mut engine = crate::engine::make(&sup.machine, settings.engine)?;
    engine.set_nonlinear(&values)?;
    let layout = Layout::new(&sup.machine, files);
    let states = fit::states_with(&sup.machine, files, &values)?;
    let mut acc = StreamingQr::new(layout.columns(), options.block);
    fit::for_each_row(engine.as_mut(), files, &states, &layout, |_, x, y| {
        acc.push(x, y)
    })?;
    let red = acc.finish();
    let n_base = m.coefficients.len();
    let width = layout.columns();
    let base_mask: Vec<bool> = (0..width)
        .map(|j| j < n_base || j >= layout.coefficients)
        .collect();
    // Everything is done on the columns of R, whose inner products are those of the columns of
    // X. An orthonormal basis of the base model's columns first; then each candidate column
    // with the base projected out, once. A candidate column the base (or the candidate's own
    // earlier columns) already spans is dropped: a spline with more knots shares its `s`, `s²`
    // with the one in the model. (An unpivoted re-triangularisation of the restricted columns
    // cannot be used here: after a dependent column its triangle is meaningless.)
    let column = |j: usize| -> Vec<f64> { (0..red.r.nrows()).map(|i| red.r[(i, j)]).collect() };
    let mut base_basis: Vec<Vec<f64>> = Vec::new();
    for j in (0..width).filter(|&j| base_mask[j]) {
        let mut v = column(j);
        project_out(&mut v, &base_basis);
        extend(&mut base_basis, v, red.norms[j]);
    }
    let base_rank = base_basis.len();
    let mut y = column(width);
    project_out(&mut y, &base_basis);
    let rss_base = dot(&y, &y);
    let mut outside: HashMap<usize, Vec<f64>> = HashMap::new();
    let rows = red.rows as f64;
    let s = m.units.error.scale;

    let mut tested: Vec<(usize, Finding)> = Vec::new();
    for (k, terms) in &columns {
        let mut own: Vec<Vec<f64>> = Vec::new();
        let mut kept = Vec::with_capacity(terms.len());
        // Whether the line can be written to add exactly what is new (see below).
        let mut appliable = true;
        for cols in terms {
            let before = own.len();
            for &j in cols {
                let mut v = outside
                    .entry(j)
                    .or_insert_with(|| {
                        let mut v = column(j);
                        project_out(&mut v, &base_basis);
                        v
                    })
                    .clone();
                project_out(&mut v, &own);
                extend(&mut own, v, red.norms[j]);
            }
            let new = own.len() - before;
            kept.push(new > 0);
            appliable &= !cols.is_empty() && (new == 0 || new == cols.len());
        }
        let added = own.len();
        // A candidate the model already contains, or one the data cannot see, adds nothing.
        // Terms the model wholly spans are left out of the line (`restate`), so that what is
        // applied adds exactly `added` coefficients and the refit stays identifiable. A term
        // the model spans in part (the `s` of an Abbe spline that a constant and a coupling
        // elsewhere already make) cannot be: a line adds all of a term's functions or none,
        // and with all of them the refit would be rank-deficient (E0601). Such a candidate is
        // not proposed, nor one whose terms could not be told apart in the super-model.
        if added == 0 || !appliable {
            continue;
        }
        let mut e = y.clone();
        project_out(&mut e, &own);
        let rss = dot(&e, &e);
        let dof = rows - (base_rank + added) as f64;
        if dof <= 0.0 || rss <= 0.0 {
            continue;
        }
        let f = ((rss_base - rss) / added as f64) / (rss / dof);
        let p = FisherSnedecor::new(added as f64, dof)
            .map(|d| 1.0 - d.cdf(f.max(0.0)))
            .unwrap_or(1.0);
        tested.push((
            *k,
            Finding {
                candidate: library::restate(&proposals[*k], &kept),
                columns: added,
                explained: ((rss_base - rss) / rss_base).max(0.0),
                f,
                p,
                p_adjusted: 1.0,
                significant: false,
                rms_after: (rss / rows).sqrt() / s,
            },
        ));
    }
    // Holm–Bonferroni over every candidate tested.
    let n = tested.len();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| tested[a].1.p.total_cmp(&tested[b].1.p));
    let mut running: f64 = 0.0;
    for (rank, &i) in order.iter().enumerate() {
        let adj = ((n - rank) as f64 * tested[i].1.p).min(1.0);
        running = running.max(adj);
        tested[i].1.p_adjusted = running;
        tested[i].1.significant = running < settings.alpha;
    }
    // One finding per group (a lag at its best time constant).
    let mut best: HashMap<String, Finding> = HashMap::new();
    for (k, f) in tested {
        let g = proposals[k].group.clone();
        match best.get(&g) {
            Some(b) if b.f >= f.f => {}
            _ => {
                best.insert(g, f);
            }
        }
    }
    let mut findings: Vec<Finding> = best.into_values().collect();
    findings.sort_by(|a, b| {
        b.significant
            .cmp(&a.significant)
            .then(b.explained.total_cmp(&a.explained))
    });
    Ok(findings)
}

/// Residuals binned along every variable, and the regions where they exceed what the noise
/// and the model's uncertainty allow (each residual's variance is σ̂²(1 − h)).
fn regions(
    m: &Machine,
    rows: &[Located],
    base: &FitResult,
    settings: &Settings,
) -> (Vec<Region>, Vec<Bin>) {
    let vars = variables(m);
    let sigma = base.sigma / m.units.error.scale;
    let comps: Vec<u8> = {
        let mut c: Vec<u8> = rows.iter().map(|r| r.component).collect();
        c.sort_unstable();
        c.dedup();
        c
    };
    // The number of tests, for a Bonferroni threshold on the bins.
    let tests = (comps.len() * vars.len() * settings.bins * 2).max(1) as f64;
    let chi = |r: &[&Located]| -> (f64, f64, f64) {
        let n = r.len() as f64;
        let stat: f64 = r
            .iter()
            .map(|x| x.residual.powi(2) / (sigma * sigma * (1.0 - x.leverage).max(1e-9)))
            .sum();
        let p = ChiSquared::new(n.max(1.0))
            .map(|d| 1.0 - d.cdf(stat))
            .unwrap_or(1.0);
        let rms = (r.iter().map(|x| x.residual.powi(2)).sum::<f64>() / n.max(1.0)).sqrt();
        let allowed = sigma
            * (r.iter().map(|x| 1.0 - x.leverage).sum::<f64>() / n.max(1.0))
                .max(0.0)
                .sqrt();
        (p, rms, allowed)
    };
    let mut bins = Vec::new();
    let mut found: Vec<Region> = Vec::new();
    for &c in &comps {
        let mine: Vec<&Located> = rows.iter().filter(|r| r.component == c).collect();
        let cname = component_name(c).to_string();
        // A component worse than the noise everywhere is one statement, not one per variable;
        // the bins then look for where it is worse than the component's own level.
        let (p_all, rms_all, allowed_all) = chi(&mine);
        let throughout = p_all < settings.alpha / tests && rms_all > 1.2 * allowed_all;
        if throughout {
            found.push(Region {
                component: cname.clone(),
                conditions: vec!["throughout the workspace".into()],
                ratio: rms_all / allowed_all.max(f64::MIN_POSITIVE),
                rows: mine.len(),
                p: p_all,
                text: format!(
                    "{cname} residuals are {:.1}× what the noise allows (σ̂ = {} {}) throughout the workspace",
                    rms_all / allowed_all.max(f64::MIN_POSITIVE),
                    nice(sigma),
                    m.units.error.name
                ),
            });
        }
        let level = if throughout {
            rms_all / allowed_all.max(f64::MIN_POSITIVE)
        } else {
            1.0
        };
        // The direction of motion: a residual that shifts with it is a backlash or hysteresis.
        for (a, axis) in m.axes.iter().enumerate() {
            let side = |d: f64| -> Vec<f64> {
                mine.iter()
                    .filter(|r| r.dirs.get(a) == Some(&d))
                    .map(|r| r.residual)
                    .collect()
            };
            let (plus, minus) = (side(1.0), side(-1.0));
            if plus.len() < 10 || minus.len() < 10 {
                continue;
            }
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
            let shift = mean(&plus) - mean(&minus);
            let se = sigma * (1.0 / plus.len() as f64 + 1.0 / minus.len() as f64).sqrt();
            let z = shift / se.max(f64::MIN_POSITIVE);
            let p = 2.0
                * (1.0
                    - statrs::distribution::Normal::new(0.0, 1.0)
                        .map(|d| d.cdf(z.abs()))
                        .unwrap_or(1.0));
            if p < settings.alpha / tests && shift.abs() > 0.5 * sigma {
                found.push(Region {
                    component: cname.clone(),
                    conditions: vec![format!("direction of motion of {}", axis.name)],
                    ratio: shift.abs() / sigma.max(f64::MIN_POSITIVE),
                    rows: plus.len() + minus.len(),
                    p,
                    text: format!(
                        "{cname} residuals shift by {} {} between the two directions of motion of {} ({:.1} σ̂)",
                        nice(shift),
                        m.units.error.name,
                        axis.name,
                        shift.abs() / sigma.max(f64::MIN_POSITIVE)
                    ),
                });
            }
        }
        for (v, (vname, unit)) in vars.iter().enumerate() {
            let vals: Vec<f64> = mine
                .iter()
                .filter_map(|r| r.values.get(v).copied())
                .filter(|x| x.is_finite())
                .collect();
            if vals.len() < 2 * settings.bins {
                continue;
            }
            let (lo, hi) = vals
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                    (a.min(*x), b.max(*x))
                });
            if !(hi > lo) {
                continue;
            }
            let width = (hi - lo) / settings.bins as f64;
            let mut flagged: Vec<(usize, f64, f64, usize)> = Vec::new();
            for b in 0..settings.bins {
                let (blo, bhi) = (lo + b as f64 * width, lo + (b + 1) as f64 * width);
                let inside: Vec<&Located> = mine
                    .iter()
                    .copied()
                    .filter(|r| {
                        r.values.get(v).is_some_and(|x| {
                            *x >= blo && (*x < bhi || (b + 1 == settings.bins && *x <= bhi))
                        })
                    })
                    .collect();
                if inside.is_empty() {
                    continue;
                }
                let (p, rms, allowed) = chi(&inside);
                let mean = inside.iter().map(|r| r.residual).sum::<f64>() / inside.len() as f64;
                bins.push(Bin {
                    component: cname.clone(),
                    variable: vname.clone(),
                    unit: unit.clone(),
                    lo: blo,
                    hi: bhi,
                    rows: inside.len(),
                    mean,
                    rms,
                    allowed,
                });
                // Against the component's own level when it is raised everywhere: a bin is
                // notable for being worse than the rest, not for sharing the common excess.
                let ratio = rms / (allowed * level).max(f64::MIN_POSITIVE);
                let excess = if throughout {
                    let n = inside.len() as f64;
                    let stat: f64 = inside
                        .iter()
                        .map(|x| x.residual.powi(2) / (rms_all * rms_all))
                        .sum();
                    ChiSquared::new(n.max(1.0))
                        .map(|d| 1.0 - d.cdf(stat))
                        .unwrap_or(1.0)
                } else {
                    p
                };
                if excess < settings.alpha / tests && ratio > 1.5 {
                    flagged.push((b, ratio, excess, inside.len()));
                }
            }
            // Adjacent flagged bins form one region.
            let mut i = 0;
            while i < flagged.len() {
                let mut j = i;
                while j + 1 < flagged.len() && flagged[j + 1].0 == flagged[j].0 + 1 {
                    j += 1;
                }
                let (b0, b1) = (flagged[i].0, flagged[j].0);
                let (rlo, rhi) = (lo + b0 as f64 * width, lo + (b1 + 1) as f64 * width);
                let cond = if b0 == 0 && b1 + 1 == settings.bins {
                    format!("all {vname}")
                } else if b0 == 0 {
                    format!("{vname} < {} {unit}", nice(rhi))
                } else if b1 + 1 == settings.bins {
                    format!("{vname} > {} {unit}", nice(rlo))
                } else {
                    format!("{} {unit} < {vname} < {} {unit}", nice(rlo), nice(rhi))
                };
                if b0 == 0 && b1 + 1 == settings.bins {
                    // Every bin: nothing local about it (said once above).
                    i = j + 1;
                    continue;
                }
                let ratio = flagged[i..=j].iter().map(|f| f.1).fold(0.0, f64::max) * level;
                let p = flagged[i..=j].iter().map(|f| f.2).fold(1.0, f64::min);
                let count = flagged[i..=j].iter().map(|f| f.3).sum();
                found.push(Region {
                    component: cname.clone(),
                    conditions: vec![cond.clone()],
                    ratio,
                    rows: count,
                    p,
                    text: format!(
                        "{cname} residuals are {:.1}× what the noise allows (σ̂ = {} {}) for {cond}",
                        ratio,
                        nice(sigma),
                        m.units.error.name
                    ),
                });
                i = j + 1;
            }
        }
    }
    found.sort_by(|a, b| b.ratio.total_cmp(&a.ratio));
    (combine(found), bins)
}

/// Pairs the strongest one-variable regions of the same component into two-variable
/// statements where both hold ("ez … for Y > 420 mm and X < 150 mm").
fn combine(found: Vec<Region>) -> Vec<Region> {
    let mut out: Vec<Region> = Vec::new();
    for r in found {
        let local = |o: &Region| {
            o.conditions
                .iter()
                .all(|c| c != "throughout the workspace" && !c.starts_with("direction of motion"))
        };
        if let Some(prev) = out.iter_mut().find(|o| {
            local(o)
                && local(&r)
                && o.component == r.component
                && o.conditions.len() == 1
                && !o.conditions.iter().any(|c| {
                    c.split_whitespace().next() == r.conditions[0].split_whitespace().next()
                })
        }) {
            prev.conditions.extend(r.conditions.clone());
            prev.text = format!("{} and {}", prev.text, r.conditions.join(" and "));
            continue;
        }
        out.push(r);
    }
    out
}

fn nice(v: f64) -> String {
    let a = v.abs();
    let digits = if a >= 100.0 {
        0
    } else if a >= 10.0 {
        1
    } else if a >= 1.0 {
        2
    } else {
        3
    };
    format!("{:.*}", digits, v)
}
