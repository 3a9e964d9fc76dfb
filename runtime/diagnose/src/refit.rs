//! The numbers a candidate with a fitted non-linear parameter states come from the refit that
//! adding its line gives, not from the scan that found it: the scan tests a wavelength or time
//! constant on a grid, and the refit moves it (and the residual level with it).

use kin_compiler::{compile, Compiled};

use super::analyse::DiagnoseError;
use super::periodic;
use super::{Finding, Fitted};
use kin_estimate::fit::{self, DataSet};

/// `source` with `line` added to the last `errors` block (or a new one).
fn with_line(source: &str, line: &str) -> Result<String, DiagnoseError> {
    let file = kin_compiler::syntax::parse_file(source)
        .map_err(|d| DiagnoseError::Candidates(d.message))?;
    let (at, open, close) = match file.machine.errors_close() {
        Some(at) => (at, "", ""),
        None => (file.machine.span.end.saturating_sub(1), "errors {\n", "}\n"),
    };
    let (head, tail) = (
        source.get(..at).unwrap_or(""),
        source.get(at..).unwrap_or(""),
    );
    Ok(format!("{head}\n{open}{line}\n{close}{tail}"))
}

/// The model `source` with `line` added, compiled and fitted to `files`; `None` when it does
/// not compile or its fit fails.
pub(super) fn with(
    line: &str,
    source: &str,
    files: &[DataSet],
    options: &fit::Options,
    engine: kin_model::engine::Engine,
) -> Result<Option<(Compiled, fit::FitResult)>, DiagnoseError> {
    let Some(c) = compile(&with_line(source, line)?).compiled else {
        return Ok(None);
    };
    let r = {
        let mut eval = kin_model::engine::make(&c.machine, engine)?;
        fit::fit(&c, eval.as_mut(), files, &[], options, &mut |_, _| {}).ok()
    };
    Ok(r.map(|r| (c, r)))
}

/// Refits the model with the finding's line and states the refit's values: the residual RMS
/// after, each new non-linear parameter with its standard error, and the line with the fitted
/// values as its start values. A refit that fails leaves the finding as the scan stated it.
pub(super) fn restate(
    finding: &mut Finding,
    base: &Compiled,
    source: &str,
    files: &[DataSet],
    options: &fit::Options,
    engine: kin_model::engine::Engine,
    alpha: f64,
) -> Result<(), DiagnoseError> {
    let refit = |line: &str| with(line, source, files, options, engine);
    let Some((mut c, mut r)) = refit(&finding.candidate.text)? else {
        return Ok(());
    };
    // A series' top harmonic is tested again with the wavelength fitted: at the scanned
    // wavelength, a small phase drift over many periods makes higher harmonics look needed.
    while let Some((top, at)) = periodic::top_harmonic(&finding.candidate.text) {
        if top < 2 {
            break;
        }
        let mut line = finding.candidate.text.clone();
        line.replace_range(at, &(top - 1).to_string());
        let line = line.replace("harmonics 1..1,", "harmonics 1,");
        let Some((c1, r1)) = refit(&line)? else {
            break;
        };
        if significant_gain(&r1, &r, alpha) {
            break;
        }
        finding.candidate.explanation = finding
            .candidate
            .explanation
            .replace(&periodic::phrase(top), &periodic::phrase(top - 1));
        finding.candidate.text = line;
        finding.columns = finding.columns.saturating_sub(2);
        (c, r) = (c1, r1);
    }
    // One effect seen in several components: the pitch and yaw a leadscrew's nut gives its
    // carriage repeat at the screw's wavelength; one heat source behind one lag expands the
    // tool along several directions. A companion joins the line (`X.tx, X.ry += …`, one
    // wavelength or time constant for all) when the joint refit improves on the line without
    // it (partial F-test of its columns, Bonferroni over the companions tried), and the same
    // terms with a parameter of their own do not improve on the joint one (partial F-test of
    // the one parameter more): otherwise it is another effect, for a line of its own.
    let (companions, same) = companions(&finding.candidate);
    let level = alpha / companions.len().max(1) as f64;
    let single = r.rows;
    for extra in companions {
        let line = &finding.candidate.text;
        let Some((targets, rhs)) = line.split_once(" += ") else {
            break;
        };
        let joint = format!("{targets}, {extra} += {rhs}");
        let Some((cj, rj)) = refit(&joint)? else {
            continue;
        };
        if !significant_gain(&r, &rj, level) {
            continue;
        }
        let apart = format!("{line}\n{extra} += {rhs}");
        if let Some((_, ra)) = refit(&apart)? {
            if significant_gain(&rj, &ra, alpha) {
                continue;
            }
        }
        let added = rj.solution.rank.saturating_sub(r.solution.rank);
        if r.solution.rss > 0.0 && rj.solution.rss > 0.0 && single > 0 {
            let n = single as f64;
            finding.bic += n * (rj.solution.rss / r.solution.rss).ln() + added as f64 * n.ln();
        }
        finding.columns += added;
        finding.candidate.text = joint;
        finding
            .candidate
            .explanation
            .push_str(&format!("; seen also in {extra} {same}"));
        finding.candidate.also.push(extra);
        (c, r) = (cj, rj);
    }

    let Some(nl) = &r.nonlinear else {
        return Ok(());
    };
    let s = c.machine.units.error.scale;
    let all: Vec<f64> = r.residuals.iter().map(|x| x.residual / s).collect();
    finding.rms_after = fit::report::rms(&all);
    let mut fitted = Vec::new();
    for (i, p) in c.machine.nonlinear.iter().enumerate() {
        if !p.fitted || base.machine.nonlinear.iter().any(|q| q.name == p.name) {
            continue;
        }
        let (Some(&v), Some(se)) = (nl.values.get(i), nl.se.get(i).copied().flatten()) else {
            continue;
        };
        let u = &p.unit;
        fitted.push(Fitted {
            name: p.name.clone(),
            value: u.from_si(v) - u.from_si(0.0),
            se: u.from_si(se) - u.from_si(0.0),
            unit: u.name.clone(),
        });
    }
    // A warm-up whose fitted time constant is shorter than the time between measurements is
    // complete from the first rows on: the data see a constant, and a constant the model lacks
    // (an offset along the tool's direction) takes this shape. Say so before it is applied.
    if let Some(step) = time_step(files) {
        for lag in c.machine.lags.iter().filter(|l| l.warmup) {
            let i = lag.tau.index;
            let (Some(p), Some(&tau)) = (c.machine.nonlinear.get(i), nl.values.get(i)) else {
                continue;
            };
            let new = p.fitted && !base.machine.nonlinear.iter().any(|q| q.name == p.name);
            if new && tau < step {
                let u = &p.unit;
                let at = |v: f64| {
                    format!(
                        "{} {}",
                        significant(u.from_si(v) - u.from_si(0.0), 0.0),
                        u.name
                    )
                };
                finding
                    .plausibility
                    .get_or_insert_with(Default::default)
                    .warnings
                    .push(format!(
                        "the fitted warm-up time constant ({}) is shorter than the time between measurements ({}): the data see a constant from the first rows on, not a warm-up (a constant the model lacks looks alike)",
                        at(tau),
                        at(step)
                    ));
            }
        }
    }
    finding.candidate.text = with_values(&finding.candidate.text, &fitted);
    for f in &fitted {
        let what = f.name.rsplit('.').next().unwrap_or(&f.name);
        finding.candidate.explanation.push_str(&format!(
            "; refit with this line: {what} {} ± {} {} (2σ)",
            significant(f.value, f.se),
            significant(2.0 * f.se, f.se),
            f.unit
        ));
    }
    finding.fitted = fitted;
    Ok(())
}

/// One finding per effect: a line with several targets is reached from the finding of each
/// of its components (`tool.tz` joined by `tool.tx`, and `tool.tx` by `tool.tz`). A finding
/// whose components all belong to another finding's joint line of the same family is dropped,
/// the one kept being led by the component that showed the effect most (then by text), so that
/// its parameter is named after that component.
pub(super) fn one_per_effect(findings: &mut Vec<Finding>) -> Vec<Finding> {
    fn set(f: &Finding) -> Vec<&str> {
        let mut v: Vec<&str> = std::iter::once(f.candidate.target.as_str())
            .chain(f.candidate.also.iter().map(String::as_str))
            .collect();
        v.sort_unstable();
        v
    }
    let covered = |b: &Finding, a: &Finding| {
        let (sa, sb) = (set(a), set(b));
        !a.candidate.also.is_empty()
            && a.candidate.family == b.candidate.family
            && sb.iter().all(|t| sa.contains(t))
            && (sa.len() > sb.len()
                || a.explained > b.explained
                || (a.explained == b.explained && a.candidate.text < b.candidate.text))
    };
    let drop: Vec<bool> = findings
        .iter()
        .enumerate()
        .map(|(i, b)| {
            findings
                .iter()
                .enumerate()
                .any(|(j, a)| i != j && covered(b, a))
        })
        .collect();
    let mut kept = Vec::with_capacity(findings.len());
    let mut gone = Vec::new();
    for (f, d) in findings.drain(..).zip(drop) {
        if d {
            gone.push(f);
        } else {
            kept.push(f);
        }
    }
    *findings = kept;
    gone
}

/// The components where the effect of `c`'s line is physically expected with the same
/// non-linear parameter, and how the explanation says so: for a periodic error along an axis,
/// the carriage's tilts ([`periodic::companions`]); for a tool's thermal lag (`tool.tz +=
/// lag(T, tau fit …) * const`), the tool's other translations (one heat source, one lag).
fn companions(c: &super::Candidate) -> (Vec<String>, &'static str) {
    match c.family {
        super::Family::Periodic => (
            periodic::companions(&c.target),
            "at the same wavelength (one effect: the carriage tilts with the same period)",
        ),
        super::Family::Thermal if c.text.contains("lag(") && c.text.ends_with(") * const") => {
            let Some((frame, comp)) = c.target.rsplit_once('.') else {
                return (Vec::new(), "");
            };
            let others = ["tx", "ty", "tz"]
                .iter()
                .filter(|t| **t != comp && comp.starts_with('t'))
                .map(|t| format!("{frame}.{t}"))
                .collect();
            (
                others,
                "with the same time constant (one heat source behind one lag)",
            )
        }
        _ => (Vec::new(), ""),
    }
}

/// Whether the fit `big` improves on `small` (its columns and parameters a subset) by a
/// partial F-test at `alpha`, the residual sums of squares weighted as the fits are.
fn significant_gain(small: &fit::FitResult, big: &fit::FitResult, alpha: f64) -> bool {
    let params = |r: &fit::FitResult| {
        r.solution.rank
            + r.nonlinear
                .as_ref()
                .map_or(0, |n| n.se.iter().filter(|s| s.is_some()).count())
    };
    let (p0, p1) = (params(small), params(big));
    let dof = big.rows.saturating_sub(p1) as f64;
    let q = p1.saturating_sub(p0) as f64;
    if q <= 0.0 || dof <= 0.0 || big.solution.rss <= 0.0 {
        return false;
    }
    let f = ((small.solution.rss - big.solution.rss) / q) / (big.solution.rss / dof);
    let p = kin_estimate::statistics::f_p(f, q, dof).unwrap_or(1.0);
    p < alpha
}

/// The line with the value (and unit) after each `fit` replaced by the fitted ones, in order.
fn with_values(line: &str, fitted: &[Fitted]) -> String {
    let mut out = String::new();
    let mut rest = line;
    for f in fitted {
        let Some(at) = rest.find(" fit ") else { break };
        let (head, tail) = rest.split_at(at + 5);
        // The value and its unit end at the option's `,` or the call's `)`.
        let end = tail.find([',', ')']).unwrap_or(tail.len());
        out.push_str(head);
        out.push_str(&format!("{} {}", significant(f.value, f.se), f.unit));
        rest = &tail[end..];
    }
    out.push_str(rest);
    out
}

/// `v` to one more decimal than its standard error's leading digit (at least four significant
/// digits, at most twelve decimals).
fn significant(v: f64, se: f64) -> String {
    let lead = |x: f64| x.abs().log10().floor() as i32;
    let by_se = if se > 0.0 && se.is_finite() {
        1 - lead(se)
    } else {
        0
    };
    let by_value = if v != 0.0 && v.is_finite() {
        3 - lead(v)
    } else {
        0
    };
    let decimals = by_se.max(by_value).clamp(0, 12) as usize;
    format!("{v:.decimals$}")
}

/// The median time between consecutive rows of one run, over every file (s); `None` without
/// time in the data.
fn time_step(files: &[DataSet]) -> Option<f64> {
    let mut steps = Vec::new();
    for f in files {
        let rows = f.observations.rows();
        let Some(time) = &rows.time else { continue };
        let run = |k: usize| rows.run.as_ref().and_then(|r| r.of_row.get(k).copied());
        for k in 1..time.len() {
            let dt = time[k] - time[k - 1];
            if run(k) == run(k - 1) && dt > 0.0 && dt.is_finite() {
                steps.push(dt);
            }
        }
    }
    steps.sort_by(f64::total_cmp);
    steps.get(steps.len() / 2).copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn companions_are_where_physics_expects_the_same_parameter() {
        let c = |family, target: &str, text: &str| super::super::Candidate {
            family,
            target: target.into(),
            also: Vec::new(),
            text: text.into(),
            explanation: String::new(),
            no_path: None,
        };
        use super::super::Family;
        let periodic = c(
            Family::Periodic,
            "X.tx",
            "X.tx += fourier(X, harmonics 1, wavelength fit 20 mm)",
        );
        assert_eq!(companions(&periodic).0, ["X.ry", "X.rz"]);
        let lag = c(
            Family::Thermal,
            "tool.tz",
            "tool.tz += lag(T, tau fit 30 min) * const",
        );
        assert_eq!(companions(&lag).0, ["tool.tx", "tool.ty"]);
        // A direct expansion has no parameter to share, a scale's lag no common term.
        let direct = c(Family::Thermal, "tool.tz", "tool.tz += T * const");
        assert!(companions(&direct).0.is_empty());
        let scale = c(
            Family::Thermal,
            "X.tx",
            "X.tx += lag(T, tau fit 30 min) * linear(X)",
        );
        assert!(companions(&scale).0.is_empty());
    }

    #[test]
    fn a_joint_line_is_one_finding() {
        let f = |target: &str, also: &[&str], explained: f64| Finding {
            candidate: super::super::Candidate {
                family: super::super::Family::Thermal,
                target: target.into(),
                also: also.iter().map(|s| s.to_string()).collect(),
                text: format!("{target} += lag(T, tau fit 40 min) * const"),
                explanation: String::new(),
                no_path: None,
            },
            alternatives: Vec::new(),
            separation: None,
            columns: 2,
            explained,
            f: 1.0,
            p: 0.0,
            p_adjusted: 0.0,
            significant: true,
            rms_after: 0.0,
            bic: -1.0,
            plausibility: None,
            fitted: Vec::new(),
            contradicted: Vec::new(),
            same_effect_as: Vec::new(),
        };
        let mut all = vec![
            f("tool.tx", &["tool.tz"], 0.08),
            f("tool.tz", &["tool.tx"], 0.85),
            f("tool.ty", &[], 0.01),
        ];
        one_per_effect(&mut all);
        let kept: Vec<&str> = all.iter().map(|f| f.candidate.target.as_str()).collect();
        assert_eq!(kept, ["tool.tz", "tool.ty"]);
        // A single component inside a joint line is that line's.
        let mut all = vec![f("tool.tx", &[], 0.9), f("tool.tz", &["tool.tx"], 0.5)];
        one_per_effect(&mut all);
        assert_eq!(all.len(), 1);
        assert_eq!(all[0].candidate.target, "tool.tz");
    }

    #[test]
    fn fitted_values_replace_the_scanned_ones() {
        let f = |value, se, unit: &str| Fitted {
            name: String::new(),
            value,
            se,
            unit: unit.into(),
        };
        assert_eq!(
            with_values(
                "X.tx += fourier(X, harmonics 1..2, wavelength fit 20.05 mm)",
                &[f(19.99974, 0.00053, "mm")]
            ),
            "X.tx += fourier(X, harmonics 1..2, wavelength fit 19.99974 mm)"
        );
        assert_eq!(
            with_values(
                "tool.tz += lag(T, tau fit 30 min) * const",
                &[f(40.123, 2.5, "min")]
            ),
            "tool.tz += lag(T, tau fit 40.12 min) * const"
        );
    }
}
