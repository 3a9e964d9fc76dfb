//! `kin diagnose`: where the model fails, which physical effect is missing, and (with
//! `--apply N`) adding the chosen effect to the model and watching the error fall.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_data::output;
use kin_diagnose::{self as diagnose, Diagnosis, Settings};

use crate::files;
use crate::fit::{self as fitcmd, FitArgs};
use crate::load::Failed;

pub struct DiagnoseArgs {
    pub fit: FitArgs,
    pub alpha: f64,
    pub output: Option<PathBuf>,
    pub apply: Option<usize>,
    /// Apply a candidate that is not significant.
    pub force: bool,
    /// Show what `--apply` would add; change nothing.
    pub dry_run: bool,
    /// List the candidates that are not findings, with the reason.
    pub explain: bool,
    /// The stated instrument noise on positions and on rotations.
    pub noise: Option<crate::args::Spread>,
    pub noise_tilt: Option<crate::args::Spread>,
    /// The diagnosis as text, or as the DIAGNOSE.json document alone on standard output.
    pub format: crate::Format,
}

pub fn run(a: DiagnoseArgs) -> ExitCode {
    Failed::exit(diagnose_command(&a))
}

fn diagnose_command(a: &DiagnoseArgs) -> Result<(), Failed> {
    if let Some(out) = &a.output {
        let inputs = fitcmd::inputs(&a.fit);
        let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
        files::check(out, &inputs)?;
    }
    let fitted = fitcmd::fit_quietly(&a.fit)?;
    // The pass over the rows and the refits report how far they are: a bar on a terminal
    // (tens of seconds at 10⁵ poses), a spinner until the first report.
    let bar = indicatif::ProgressBar::new_spinner();
    crate::warnings::hush(&bar);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} diagnosing ({elapsed})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let progress = {
        let bar = bar.clone();
        let style = indicatif::ProgressStyle::with_template(
            "{msg:>28} [{bar:30}] {human_pos}/{human_len} ({elapsed}, {eta} left)",
        )
        .map(|s| s.progress_chars("=> "))
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
        diagnose::Progress::new(move |step, done, total| {
            let msg = match step {
                diagnose::Step::Rows => "testing the candidate effects",
                diagnose::Step::Pairs => "comparing the effects found",
                diagnose::Step::Refits => "refitting what was found",
            };
            if bar.length() != Some(total) || bar.message() != msg {
                bar.set_style(style.clone());
                bar.set_message(msg);
                bar.set_length(total);
                bar.reset_elapsed();
            }
            bar.set_position(done);
        })
    };
    let settings = Settings {
        alpha: a.alpha,
        engine: a.fit.engine,
        noise: a.noise.as_ref().map(|n| n.si),
        noise_tilt: a.noise_tilt.as_ref().map(|n| n.si),
        progress,
        ..Settings::default()
    };
    let diagnosis = diagnose::diagnose(
        &fitted.compiled,
        &fitted.source,
        &fitted.files,
        &fitted.result,
        &fitted.options,
        &settings,
    );
    bar.finish_and_clear();
    let diagnosis = diagnosis.map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    if a.format == crate::Format::Json {
        // Standard output holds the document alone (spec/json.md); `--apply` is refused with
        // `--format json` by the command line.
        let json = fitcmd::to_json(&diagnosis)?;
        if let Some(out) = &a.output {
            files::write(out, json.as_bytes())?;
        }
        println!("{json}");
        return Ok(());
    }
    let mut said = text(&diagnosis, fitted.report.sigma, fitted.report.rms);
    if let Some(note) = fitcmd::mixed_units(&fitted.report) {
        // σ̂ of rows in µm and µrad is in neither unit alone: say so under the header.
        let at = said.find('\n').map_or(said.len(), |i| i + 1);
        said.insert_str(at, &format!("  ({note})\n"));
    }
    match a.apply {
        // The user chose N from the list already printed: the header, then what is added.
        Some(_) => {
            let header = said.lines().next().unwrap_or_default();
            println!("{header}");
        }
        None => print!("{said}"),
    }
    if a.explain {
        print!("{}", dropped(&diagnosis));
    }
    if let Some(out) = &a.output {
        files::write(out, fitcmd::to_json(&diagnosis)?.as_bytes())?;
        println!("wrote {}", out.display());
    }
    let Some(n) = a.apply else {
        return Ok(());
    };
    let Some(finding) = n.checked_sub(1).and_then(|i| diagnosis.findings.get(i)) else {
        eprintln!(
            "error: there is no candidate {n}; the list has {}",
            diagnosis.findings.len()
        );
        return Err(Failed::USAGE);
    };
    if !finding.significant && !a.force {
        eprintln!(
            "error: candidate {n} (`{}`) is not significant (adjusted p = {} at α = {}); the model was not changed. \
             Add it anyway with --apply {n} --force",
            finding.candidate.text, probability(finding.p_adjusted), diagnosis.alpha
        );
        return Err(Failed::INPUT);
    }
    if let (Some(c), false) = (finding.contradiction(), a.force) {
        eprintln!(
            "error: candidate {n} (`{}`) is contradicted by the data: {c}; the model was not changed. \
             Add it anyway with --apply {n} --force",
            finding.candidate.text
        );
        return Err(Failed::INPUT);
    }
    let doubts = finding
        .plausibility
        .as_ref()
        .map(|p| p.warnings.join("; "))
        .filter(|w| !w.is_empty());
    if let (Some(doubts), false) = (&doubts, a.force) {
        eprintln!(
            "error: candidate {n} (`{}`) makes the refit doubtful ({doubts}); the model was not changed. \
             Add it anyway with --apply {n} --force",
            finding.candidate.text
        );
        return Err(Failed::INPUT);
    }
    let model = &a.fit.machine;
    let revision = with_line(
        &fitted.source,
        &finding.candidate.text,
        &finding.candidate.explanation,
    )?;
    if a.dry_run {
        println!(
            "\n--dry-run: would add to {} at line {} (nothing was written):",
            model.display(),
            revision.line
        );
        for l in &revision.added {
            println!("+ {l}");
        }
        return Ok(());
    }
    replace_model(model, &fitted.source, &revision.text)?;
    println!(
        "\nadded to {}: {}\n(the previous text is in {})\n",
        model.display(),
        finding.candidate.text,
        previous_path(model).display()
    );
    // The fit before the change is recorded with the text it was made of, so the refit prints
    // the fall and the revision can be restored from the history. Its own comparison with the
    // round before was printed by that round: not again here.
    let _ = fitcmd::record_quietly(model, &fitted, Some(&fitted.source));
    let mut refit = fitcmd::fit_quietly(&a.fit)?;
    write_back(
        model,
        &mut refit,
        revision.line..revision.line + revision.added.len(),
    )?;
    fitcmd::finish(&a.fit, &refit)?;
    Ok(())
}

/// After the refit of an `--apply`: the fitted non-linear values of the added line (its lines
/// `lines`, 1-based) become their declarations' start values in the model file, and the refit
/// is recorded as a fit of that text (the same model, started at its optimum). Fitted values
/// of the model's other declarations are offered, not written.
fn write_back(
    model: &Path,
    refit: &mut fitcmd::Fitted,
    lines: std::ops::Range<usize>,
) -> Result<(), Failed> {
    let all = crate::writeback::fitted_values(&refit.source, &refit.compiled, &refit.report);
    let line_of = |at: usize| {
        refit
            .source
            .get(..at)
            .map(|t| t.matches('\n').count() + 1)
            .unwrap_or(0)
    };
    let (added, others): (Vec<_>, Vec<_>) = all
        .iter()
        .partition(|f| lines.contains(&line_of(f.at.start)));
    let added: Vec<_> = added.into_iter().filter(|f| f.old != f.new).collect();
    if !added.is_empty() {
        let text = crate::writeback::rewrite(&refit.source, &added);
        amend_model(model, &refit.source, &text)?;
        for f in &added {
            println!(
                "wrote the fitted {} into {}: `fit {}` → `fit {}` (± {:.3} {})",
                f.name,
                model.display(),
                f.old,
                f.new,
                f.se,
                f.unit
            );
        }
        refit.report.model_hash = kin_estimate::fit::report::model_hash(&text);
        refit.source = text;
    }
    for f in others.iter().filter(|f| f.old != f.new) {
        println!(
            "also fitted: {} (declared `fit {}`) is {} ± {:.3} {}; edit the model to start it there",
            f.name, f.old, f.new, f.se, f.unit
        );
    }
    Ok(())
}

/// Where `--apply` keeps the model's text from before its last change.
pub fn previous_path(model: &Path) -> PathBuf {
    output::beside(model, ".previous")
}

/// A model's text with a line added, and what was added where (for `--dry-run`).
pub struct Revision {
    pub text: String,
    /// The added lines, as they appear in the new text.
    pub added: Vec<String>,
    /// The 1-based line of the new text where they start.
    pub line: usize,
}

/// `source` with `line` (and a comment saying why) at the end of the model's last `errors`
/// block.
pub fn with_line(source: &str, line: &str, why: &str) -> Result<Revision, Failed> {
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
    let added = vec![
        format!("        // added by `kin diagnose`: {why}"),
        format!("        {line}"),
    ];
    let text = format!("{before}\n\n{}\n    {after}", added.join("\n"));
    Ok(Revision {
        text,
        // `before`, then an empty line.
        line: before.lines().count() + 2,
        added,
    })
}

/// Replaces the model file `path`, whose text was `base` when it was read, with `revised`.
/// Under an advisory lock on `PATH.lock` (so two `--apply` runs take turns) the file is read
/// again: if it is no longer `base` — edited meanwhile, or changed by another `--apply` — nothing
/// is written and the command fails, so no edit is reverted and no added line is lost. `base`
/// is kept in `PATH.previous` before the model is replaced.
pub fn replace_model(path: &Path, base: &str, revised: &str) -> Result<(), Failed> {
    replace(path, base, revised, true)
}

/// As [`replace_model`], without keeping `base` in `PATH.previous`: for a second step of the
/// same `--apply`, so `PATH.previous` stays the text from before the command.
fn amend_model(path: &Path, base: &str, revised: &str) -> Result<(), Failed> {
    replace(path, base, revised, false)
}

fn replace(path: &Path, base: &str, revised: &str, keep: bool) -> Result<(), Failed> {
    let _lock = output::lock_beside(path).map_err(|e| {
        eprintln!("error: cannot lock `{}`: {e}", path.display());
        Failed::USAGE
    })?;
    let now = std::fs::read_to_string(path).map_err(|e| {
        eprintln!("error: cannot read `{}` again: {e}", path.display());
        Failed::USAGE
    })?;
    if now != base {
        eprintln!(
            "error: `{}` changed since this command read it (edited, or revised by another `kin diagnose --apply`); \
             it was not written, so the change is kept. Diagnose it again.",
            path.display()
        );
        return Err(Failed::USAGE);
    }
    if keep {
        files::write(&previous_path(path), base.as_bytes())?;
    }
    files::write(path, revised.as_bytes())
}

/// The terminal report: where, then against the noise, then what.
pub fn text(d: &Diagnosis, sigma: f64, rms: f64) -> String {
    let u = &d.error_unit;
    let mut s = if !d.noise.per_file.is_empty() {
        format!(
            "diagnosis of `{}`: σ̂/σ = {:.4}, residual RMS {:.4} σ (every fit weighs each row by its own file's σ)\n",
            d.machine, sigma, rms
        )
    } else if d.weighted {
        format!(
            "diagnosis of `{}`: σ̂/σ = {:.4}, residual RMS {:.4} σ (every fit weighs each row by its stated noise)\n",
            d.machine, sigma, rms
        )
    } else {
        format!(
            "diagnosis of `{}`: σ̂ = {:.4} {u}, residual RMS {:.4} {u}\n",
            d.machine, sigma, rms
        )
    };
    // With a stated noise the residual level after a line is a multiple of it.
    let after_unit = if d.weighted { "σ" } else { u.as_str() };
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
    // With a σ per file: each file's scatter against its own noise.
    for f in &d.noise.per_file {
        let kind = match f.kind {
            kin_estimate::fit::components::RowKind::Position => "positions",
            kin_estimate::fit::components::RowKind::Rotation => "rotations",
        };
        let against = match f.p {
            Some(p) if f.stated => format!(
                "{:.2}× its stated σ = {:.4} {} (χ² p {}): {}",
                f.ratio,
                f.sigma,
                f.unit,
                pvalue(p),
                if p >= d.alpha {
                    "down to its noise"
                } else {
                    "more than its instrument explains"
                }
            ),
            _ => "its σ, estimated by the fit (no noise stated for it)".to_string(),
        };
        s.push_str(&format!(
            "  {} {kind}: σ̂ = {:.4} {}, {against}; {} outliers of {} rows\n",
            f.file, f.sigma_hat, f.unit, f.outliers, f.rows
        ));
    }
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
            "  {:>2}. {:<19} explains {:>5.1} % of the residual variance with {} column{} (F = {:.1}, p {}, ΔBIC = {:.0}, RMS → {:.4} {after_unit})\n      {}\n      add: {}\n",
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
        // Another reading of an effect a line above explains: name it by its number.
        let earlier: Vec<String> = f
            .same_effect_as
            .iter()
            .filter_map(|t| {
                significant
                    .iter()
                    .take(i)
                    .position(|g| g.candidate.text == *t)
                    .map(|k| (k + 1).to_string())
            })
            .collect();
        if !earlier.is_empty() {
            s.push_str(&format!(
                "      the same effect as {}: with {} added, this one adds nothing significant\n",
                earlier.join(" and "),
                if earlier.len() == 1 {
                    "that line"
                } else {
                    "either line"
                }
            ));
        }
        if let Some(sep) = &f.separation {
            s.push_str(&format!(
                "      the data cannot decide between these readings: {sep}\n"
            ));
        }
        if let Some(c) = f.contradiction() {
            s.push_str(&format!("      contradicted: {c}\n"));
        }
        for w in f.plausibility.iter().flat_map(|p| &p.warnings) {
            s.push_str(&format!("      doubtful: {w}\n"));
        }
        if let Some(why) = &f.candidate.no_path {
            s.push_str(&format!("      no physical path: {why}\n"));
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

/// The candidates proposed that are not findings, each with its reason (`--explain`).
fn dropped(d: &Diagnosis) -> String {
    let mut s = format!(
        "\ncandidates proposed that are not findings ({})\n",
        d.dropped.len()
    );
    for c in &d.dropped {
        s.push_str(&format!("  {}\n      {}\n", c.text, c.reason));
    }
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
        None if !d.noise.per_file.is_empty() => {
            "no file's noise stated: each file's σ is estimated by the fit and every row judged against its own file's σ̂ (below)".to_string()
        }
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
        // Relative to σ̂ alone the residuals are "consistent" only where no region stands
        // out: regions that fail (above) are what the library did not account for.
        (None, None) if !d.regions.is_empty() => format!(
            "but the residuals exceed the model's own residual scatter in {} region{} (above), which no effect of the library accounts for: something it does not propose is missing there; with no instrument noise stated the absolute level is not judged (state it with --noise)",
            d.regions.len(),
            if d.regions.len() == 1 { "" } else { "s" }
        ),
        (None, None) => format!(
            "the residuals are consistent with the model's own residual scatter (σ̂ = {:.4} {}); with no instrument noise stated this says nothing of the absolute level (state it with --noise)",
            d.sigma, d.error_unit
        ),
    }
}

/// A probability with three significant digits, never rounded onto a level it is compared
/// with (`0.0103`, not `0.01` beside α = 0.01).
fn probability(p: f64) -> String {
    if p.is_nan() || p <= 0.0 || !p.is_finite() || p >= 0.1 {
        return format!("{p:.2}");
    }
    if p < 1e-4 {
        return format!("{p:.2e}");
    }
    let decimals = (2 - p.log10().floor() as i32).max(0) as usize;
    format!("{p:.decimals$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With no noise stated and no repeated poses, the verdict under region failures says
    /// they are unexplained, never that the residuals are consistent.
    #[test]
    fn failing_regions_are_not_called_consistent() {
        let mut d = Diagnosis {
            machine: "m".into(),
            model_hash: String::new(),
            sigma: 0.2,
            rms: 0.2,
            error_unit: "um".into(),
            alpha: 0.01,
            regions: Vec::new(),
            bins: Vec::new(),
            spectra: Vec::new(),
            findings: Vec::new(),
            noise: Default::default(),
            outliers: Vec::new(),
            weighted: false,
            proposed: 0,
            dropped: Vec::new(),
        };
        assert!(verdict(&d).contains("consistent"));
        d.regions.push(diagnose::Region {
            component: "ex".into(),
            conditions: vec!["X < 100 mm".into()],
            ratio: 2.8,
            rows: 40,
            p: 1e-8,
            text: String::new(),
        });
        let v = verdict(&d);
        assert!(!v.contains("consistent"), "{v}");
        assert!(v.contains("1 region (above)"), "{v}");
    }

    #[test]
    fn probabilities_keep_three_significant_digits() {
        assert_eq!(probability(0.0103), "0.0103");
        assert_eq!(probability(0.00999), "0.00999");
        assert_eq!(probability(0.5), "0.50");
        assert_eq!(probability(3.2e-7), "3.20e-7");
        assert_eq!(probability(1.0), "1.00");
    }

    #[test]
    fn a_model_changed_since_it_was_read_is_not_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("m.kin");
        std::fs::write(&model, "base\n// edited meanwhile\n").unwrap();
        assert_eq!(
            replace_model(&model, "base\n", "base\nadded\n"),
            Err(Failed::USAGE)
        );
        assert_eq!(
            std::fs::read_to_string(&model).unwrap(),
            "base\n// edited meanwhile\n"
        );
        assert!(!previous_path(&model).exists());
    }

    #[test]
    fn an_unchanged_model_is_replaced_and_its_text_kept() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("m.kin");
        std::fs::write(&model, "base\n").unwrap();
        replace_model(&model, "base\n", "base\nadded\n").unwrap();
        assert_eq!(std::fs::read_to_string(&model).unwrap(), "base\nadded\n");
        assert_eq!(
            std::fs::read_to_string(previous_path(&model)).unwrap(),
            "base\n"
        );
    }
}
