//! Fitted non-linear values written back into a model's text (`kin diagnose --apply`): a line
//! that declares `tau fit 30 min` or `wavelength fit 20 mm` is refitted, and the value the fit
//! found becomes the declaration's new start (`tau fit 40.1 min`), so the model file says what
//! the data say and the next fit starts at the optimum.

use std::ops::Range;

use kin_compiler::Compiled;
use kin_estimate::fit::report::FitReport;

/// One fitted non-linear parameter of the model and its declaration's text.
pub struct Fitted {
    pub name: String,
    /// Byte range of the value in the model's text (the quantity after `fit`).
    pub at: Range<usize>,
    pub old: String,
    pub new: String,
    pub se: f64,
    pub unit: String,
}

/// Every non-linear parameter the fit determined (label `fitted` or `not significant`), with its declaration's value
/// in `source` and the fitted value as text to replace it.
pub fn fitted_values(source: &str, compiled: &Compiled, report: &FitReport) -> Vec<Fitted> {
    let mut out = Vec::new();
    for (i, est) in report.nonlinear.iter().enumerate() {
        // A value no better than its start is still the fit's estimate; one the data do not
        // determine is not.
        if !matches!(est.label.as_str(), "fitted" | "not significant") || !est.value.is_finite() {
            continue;
        }
        let Some(span) = compiled.map.nonlinear.get(i) else {
            continue;
        };
        let Some(text) = source.get(span.start..span.end) else {
            continue;
        };
        // The span may hold the option's name and `fit`: the value is what follows `fit`.
        let skip = text.rfind("fit ").map(|k| k + "fit ".len()).unwrap_or(0);
        let value = &text[skip..];
        let lead = value.len() - value.trim_start().len();
        let start = span.start + skip + lead;
        out.push(Fitted {
            name: est.name.clone(),
            at: start..span.end,
            old: value.trim().to_string(),
            new: format!("{} {}", significant(est.value, est.se), est.unit),
            se: est.se,
            unit: est.unit.clone(),
        });
    }
    out
}

/// `v` with as many digits as its standard error makes meaningful (two significant digits of
/// the error), at least four significant digits when the error is unknown or zero.
fn significant(v: f64, se: f64) -> String {
    let digits = if se.is_finite() && se > 0.0 {
        (1 - se.log10().floor() as i32).max(0)
    } else {
        (3 - v.abs().max(f64::MIN_POSITIVE).log10().floor() as i32).max(0)
    } as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// `source` with the values of `chosen` replaced (their ranges do not overlap).
pub fn rewrite(source: &str, chosen: &[&Fitted]) -> String {
    let mut sorted: Vec<&&Fitted> = chosen.iter().collect();
    sorted.sort_by_key(|f| std::cmp::Reverse(f.at.start));
    let mut text = source.to_string();
    for f in sorted {
        if text.get(f.at.clone()).is_some() {
            text.replace_range(f.at.clone(), &f.new);
        }
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_keep_the_digits_their_error_supports() {
        assert_eq!(significant(40.1234, 0.52), "40.12");
        assert_eq!(significant(40.1234, 3.0), "40.1");
        assert_eq!(significant(25.4012345, 0.0004), "25.40123");
        assert_eq!(significant(1234.7, 20.0), "1235");
        assert_eq!(significant(40.1234, f64::NAN), "40.12");
    }
}
