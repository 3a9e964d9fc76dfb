//! `kin diagnose`: where the model fails, which physical effect is missing, and (with
//! `--apply N`) adding the chosen effect to the model and watching the error fall.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_runtime::diagnose::{self, Diagnosis, Settings};

use crate::fit::{self as fitcmd, FitArgs};
use crate::load::Failed;

pub struct DiagnoseArgs {
    pub fit: FitArgs,
    pub alpha: f64,
    pub output: Option<PathBuf>,
    pub apply: Option<usize>,
    /// The stated instrument noise, as written (`0.3um`, `1urad`).
    pub noise: Option<String>,
    pub noise_tilt: Option<String>,
}

pub fn run(a: DiagnoseArgs) -> ExitCode {
    Failed::exit(diagnose_command(&a))
}

fn diagnose_command(a: &DiagnoseArgs) -> Result<(), Failed> {
    let parse = |text: &Option<String>, dim, what| -> Result<Option<f64>, Failed> {
        text.as_deref()
            .map(|t| match crate::load::quantity(t, dim, what) {
                Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
                Ok(_) => {
                    eprintln!("error: {what} must be a positive quantity, not `{t}`");
                    Err(Failed::USAGE)
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    Err(Failed::USAGE)
                }
            })
            .transpose()
    };
    let noise = parse(&a.noise, kin_compiler::units::Dim::LENGTH, "--noise")?;
    let noise_tilt = parse(
        &a.noise_tilt,
        kin_compiler::units::Dim::ANGLE,
        "--noise-tilt",
    )?;
    let fitted = fitcmd::fit_quietly(&a.fit)?;
    let settings = Settings {
        alpha: a.alpha,
        engine: a.fit.engine,
        noise,
        noise_tilt,
        ..Settings::default()
    };
    let diagnosis = diagnose::diagnose(
        &fitted.compiled,
        &fitted.source,
        &fitted.files,
        &fitted.result,
        &fitted.options,
        &settings,
    )
    .map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    print!(
        "{}",
        text(&diagnosis, fitted.report.sigma, fitted.report.rms)
    );
    if let Some(out) = &a.output {
        let json = serde_json::to_string_pretty(&diagnosis).map_err(|e| {
            eprintln!("error: {e}");
            Failed::USAGE
        })?;
        std::fs::write(out, json).map_err(|e| {
            eprintln!("error: cannot write `{}`: {e}", out.display());
            Failed::USAGE
        })?;
        println!("wrote {}", out.display());
    }
    if let Some(n) = a.apply {
        let Some(finding) = n.checked_sub(1).and_then(|i| diagnosis.findings.get(i)) else {
            eprintln!(
                "error: there is no candidate {n}; the list has {}",
                diagnosis.findings.len()
            );
            return Err(Failed::USAGE);
        };
        apply(
            &a.fit.machine,
            &fitted.source,
            &finding.candidate.text,
            &finding.candidate.explanation,
        )?;
        println!(
            "\nadded to {}: {}\n",
            a.fit.machine.display(),
            finding.candidate.text
        );
        // The history of the fit before the change is recorded, so the refit prints the fall.
        fitcmd::record(&a.fit.machine, &fitted.report);
        fitcmd::fit_command(&a.fit)?;
    }
    Ok(())
}

/// Adds `line` (and a comment saying why) at the end of the model's last `errors` block.
pub fn apply(path: &Path, source: &str, line: &str, why: &str) -> Result<(), Failed> {
    let file = kin_compiler::syntax::parse_file(source).map_err(|d| {
        eprintln!("error: {}", d.message);
        Failed::INPUT
    })?;
    let Some(at) = file.machine.errors_close() else {
        eprintln!("error: the model has no `errors` block to add to");
        return Err(Failed::INPUT);
    };
    let before = source.get(..at).unwrap_or("").trim_end();
    let after = source.get(at..).unwrap_or("");
    let text = format!(
        "{before}\n\n        // added by `kin diagnose`: {why}\n        {line}\n    {after}"
    );
    std::fs::write(path, text).map_err(|e| {
        eprintln!("error: cannot write `{}`: {e}", path.display());
        Failed::USAGE
    })
}

/// The terminal report: where, then against the noise, then what.
pub fn text(d: &Diagnosis, sigma: f64, rms: f64) -> String {
    let u = &d.error_unit;
    let mut s = format!(
        "diagnosis of `{}`: σ̂ = {:.4} {u}, residual RMS {:.4} {u}\n",
        d.machine, sigma, rms
    );
    let significant: Vec<_> = d.findings.iter().filter(|f| f.significant).collect();
    s.push_str("\nwhere the model fails\n");
    if d.regions.is_empty() {
        let line = if !significant.is_empty() {
            "no region stands out on its own, but the effects below are significant"
        } else if d.noise.chi2.as_ref().is_some_and(|c| !c.consistent) {
            "no region stands out: the excess over the stated noise is spread over the workspace"
        } else if d.noise.chi2.is_some() {
            "nowhere: along every axis and input the residuals are what the stated noise allows"
        } else {
            "no region stands out against the model's own residual scatter σ̂ (no instrument noise stated)"
        };
        s.push_str(&format!("  {line}\n"));
    }
    for r in d.regions.iter().take(8) {
        s.push_str(&format!(
            "  {} ({} observations, p {})\n",
            r.text,
            r.rows,
            pvalue(r.p)
        ));
    }
    if !d.outliers.is_empty() {
        s.push_str(&format!(
            "\noutliers ({}: |studentized residual| above the fit's threshold; left out of the region and noise tests)\n",
            d.outliers.len()
        ));
        for o in d.outliers.iter().take(8) {
            s.push_str(&format!(
                "  {}:{} {} residual {:.4} (studentized {:.1})\n",
                o.file, o.line, o.component, o.residual, o.studentized
            ));
        }
        if d.outliers.len() > 8 {
            s.push_str(&format!(
                "  … and {} more (see DIAGNOSE.json)\n",
                d.outliers.len() - 8
            ));
        }
    }
    s.push_str("\nagainst the noise\n");
    s.push_str(&format!("  {}\n", noise_line(d)));
    if let Some(l) = &d.noise.lack_of_fit {
        s.push_str(&format!(
            "  {} repeated poses ({} rows): pure-error σ = {:.4} {u}; lack of fit F = {:.2}, p {}{}\n",
            l.groups,
            l.rows,
            l.sigma_pure,
            l.f,
            pvalue(l.p),
            if l.consistent { "" } else { ": the model misses more than the instrument scatters" }
        ));
    }
    s.push_str(&format!("\nwhich effect is missing (partial F-tests, Holm–Bonferroni at α = {} over {} candidates; ranked by BIC)\n", d.alpha, d.findings.len()));
    if significant.is_empty() {
        let v = verdict(d);
        let join = if v.starts_with("but ") { ", " } else { ": " };
        s.push_str(&format!("  no candidate is significant{join}{v}\n"));
        if let Some(best) = d.findings.first() {
            s.push_str(&format!(
                "  (the strongest, `{}`, would explain {:.2} % with adjusted p = {:.2})\n",
                best.candidate.text,
                100.0 * best.explained,
                best.p_adjusted
            ));
        }
        return s;
    }
    for (i, f) in significant.iter().enumerate().take(10) {
        s.push_str(&format!(
            "  {:>2}. {:<19} explains {:>5.1} % of the residual variance with {} column{} (F = {:.1}, p {}, ΔBIC = {:.0}, RMS → {:.4} {u})\n      {}\n      add: {}\n",
            i + 1,
            format!("{:?}", f.candidate.family),
            100.0 * f.explained,
            f.columns,
            if f.columns == 1 { "" } else { "s" },
            f.f,
            pvalue(f.p_adjusted),
            f.bic,
            f.rms_after,
            f.candidate.explanation,
            f.candidate.text
        ));
        for alt in &f.alternatives {
            s.push_str(&format!("      or, equally on these data: {}\n", alt.text));
        }
        if let Some(sep) = &f.separation {
            s.push_str(&format!(
                "      the data cannot decide between these readings: {sep}\n"
            ));
        }
        for w in f.plausibility.iter().flat_map(|p| &p.warnings) {
            s.push_str(&format!("      doubtful: {w}\n"));
        }
    }
    if significant.len() > 10 {
        s.push_str(&format!(
            "  … and {} more significant candidates (see DIAGNOSE.json)\n",
            significant.len() - 10
        ));
    }
    s.push_str("\n  add one with `kin diagnose … --apply N` (or paste its line into the errors block), then refit\n");
    s
}

/// `= 3.2e-5`, or `< 1e-16` where the distribution's tail is below double precision.
fn pvalue(p: f64) -> String {
    if p < 1e-16 {
        "< 1e-16".into()
    } else {
        format!("= {p:.1e}")
    }
}

/// The residual level against the absolute reference that was actually tested.
fn noise_line(d: &Diagnosis) -> String {
    let u = &d.error_unit;
    match &d.noise.chi2 {
        Some(c) => format!(
            "σ̂ is {:.2}× the stated noise (χ² = {:.0} on {:.0} degrees of freedom, p {}): {}",
            c.ratio,
            c.statistic,
            c.dof,
            pvalue(c.p),
            if c.consistent {
                "consistent with it"
            } else {
                "more than the instrument explains"
            }
        ),
        None => format!(
            "no instrument noise stated (--noise, --noise-tilt): the tests are relative to the model's own residual scatter σ̂ = {:.4} {u}",
            d.sigma
        ),
    }
}

/// What "no candidate is significant" means, in the words of the test that was made.
pub fn verdict(d: &Diagnosis) -> String {
    match (&d.noise.chi2, &d.noise.lack_of_fit) {
        (Some(c), _) if c.consistent => format!(
            "the model explains the data down to the stated noise (σ̂/σ = {:.2}, χ² p = {:.2})",
            c.ratio, c.p
        ),
        (Some(c), _) => format!(
            "but σ̂ is {:.1}× the stated noise (χ² p {}): the model leaves more than the instrument's noise unexplained, and no effect of the library accounts for the rest (or the stated noise is too small)",
            c.ratio,
            pvalue(c.p)
        ),
        (None, Some(l)) if l.consistent => format!(
            "the residuals are consistent with the scatter of the {} repeated poses (lack of fit p = {:.2})",
            l.groups, l.p
        ),
        (None, Some(l)) => format!(
            "but the residuals exceed the scatter of the {} repeated poses (lack of fit p {}): something the library does not propose is missing",
            l.groups,
            pvalue(l.p)
        ),
        (None, None) => format!(
            "the residuals are consistent with the model's own residual scatter (σ̂ = {:.4} {}); with no instrument noise stated this says nothing of the absolute level (state it with --noise)",
            d.sigma, d.error_unit
        ),
    }
}
