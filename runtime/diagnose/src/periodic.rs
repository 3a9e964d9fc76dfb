//! Candidates for periodic errors along a prismatic axis (a leadscrew's pitch, a scale or
//! encoder period; thesis eq. 3.11–3.15), at the wavelengths the residual spectra show.

use kin_compiler::ir::{Axis, Machine};

use super::library::{push, round, Available, Peak, Proposal, Term};
use super::Family;

/// Appends the periodic candidates for the prismatic axis `a` (`name` its frame's name,
/// `target` the error component along its motion) at each spectral peak found for it.
pub(super) fn propose(
    out: &mut Vec<Proposal>,
    m: &Machine,
    available: &Available,
    wavelengths: &[Peak],
    a: usize,
    axis: &Axis,
    target: &str,
) {
    let length = &m.units.length;
    let fmt_len = |v: f64| format!("{} {}", round(length.from_si(v)), length.name);
    // The tested wavelength keeps the refined peak's digits: over tens of periods a
    // wavelength rounded to four digits drifts out of phase, and the series would take
    // harmonics it does not need to follow.
    let exact = |v: f64| {
        let v = length.from_si(v);
        let p = 10f64.powi(8 - v.abs().log10().ceil() as i32);
        format!("{} {}", (v * p).round() / p, length.name)
    };
    let sampled = available.sampled.get(a).copied().flatten();
    for peak in wavelengths.iter().filter(|p| p.axis == a) {
        let lambda = peak.wavelength;
        let first = out.len();
        let Some(sampling) = sampled.filter(|s| s.resolves(lambda)) else {
            continue;
        };
        if !(lambda > 0.0 && lambda < axis.range[1] - axis.range[0]) {
            continue;
        }
        let group = format!("{SERIES}{target} {}", fmt_len(lambda));
        // The Fourier series with 1, 2, … harmonics, as far as the sampling resolves them
        // (harmonic h has wavelength λ/h); `choose` keeps as many as the data support.
        let resolved = (1..=MAX_HARMONICS)
            .take_while(|&h| sampling.resolves(lambda / f64::from(h)))
            .last()
            .unwrap_or(1);
        for top in 1..=resolved {
            let hs = if top == 1 {
                "1".to_string()
            } else {
                format!("1..{top}")
            };
            let harmonics = phrase(top);
            push(
                out,
                Family::Periodic,
                target.to_string(),
                vec![Term {
                    text: format!(
                        "fourier({}, harmonics {hs}, wavelength fit {})",
                        axis.name,
                        fmt_len(lambda)
                    ),
                    test: format!(
                        "fourier({}, harmonics {hs}, wavelength {})",
                        axis.name,
                        exact(lambda)
                    ),
                    harmonic: None,
                }],
                format!(
                    "a periodic error along {} at a wavelength near {} ({harmonics}): a leadscrew pitch, a scale or encoder period",
                    axis.name,
                    fmt_len(lambda)
                ),
                Some(group.clone()),
            );
        }
        // A periodic spline, for a period whose shape is not close to a few sinusoids.
        push(
            out,
            Family::Periodic,
            target.to_string(),
            vec![Term {
                text: format!(
                    "periodic({}, wavelength fit {}, knots 2)",
                    axis.name,
                    fmt_len(lambda)
                ),
                test: format!(
                    "periodic({}, wavelength {}, knots 2)",
                    axis.name,
                    exact(lambda)
                ),
                harmonic: None,
            }],
            format!(
                "a periodic error of wavelength near {} along {}, not sinusoidal in shape: a leadscrew pitch, a scale or encoder period",
                fmt_len(lambda),
                axis.name
            ),
            Some(group),
        );
        for p in out.iter_mut().skip(first) {
            p.searched = peak.searched;
        }
    }
}

/// The components besides `target` (the component along an axis' motion, `X.tx`) where the
/// same periodic error is physically expected at the same wavelength: the pitch and yaw of the
/// carriage (`X.ry`, `X.rz`), which a leadscrew nut's wobble or a scale's mounting makes
/// periodic with the pitch. Empty for a target that is not a translation.
pub(super) fn companions(target: &str) -> Vec<String> {
    let Some((frame, comp)) = target.rsplit_once('.') else {
        return Vec::new();
    };
    let tilts: &[&str] = match comp {
        "tx" => &["ry", "rz"],
        "ty" => &["rx", "rz"],
        "tz" => &["rx", "ry"],
        _ => &[],
    };
    tilts.iter().map(|r| format!("{frame}.{r}")).collect()
}

/// How a series of harmonics 1..`top` is described.
pub(super) fn phrase(top: u32) -> String {
    match top {
        1 => "a sinusoid".to_string(),
        2 => "a sinusoid and its 2nd harmonic".to_string(),
        3 => "a sinusoid and its 2nd and 3rd harmonics".to_string(),
        _ => format!("a sinusoid and its harmonics up to the {top}th"),
    }
}

/// The top harmonic `H` of a series `fourier(V, harmonics 1..H, …)` in a line, and where its
/// number is written.
pub(super) fn top_harmonic(line: &str) -> Option<(u32, std::ops::Range<usize>)> {
    let at = line.find("fourier(")?;
    let from = at + line.get(at..)?.find("harmonics 1..")? + "harmonics 1..".len();
    let len = line.get(from..)?.find(|c: char| !c.is_ascii_digit())?;
    let h = line.get(from..from + len)?.parse().ok()?;
    Some((h, from..from + len))
}

/// The most harmonics a candidate series carries (a pitch error's shape beyond the 4th is
/// rarely above the noise, and each costs two columns).
const MAX_HARMONICS: u32 = 4;

/// The group of a periodic error's readings at one wavelength (see [`choose`]).
const SERIES: &str = "periodic series ";

/// Whether a proposal group is the readings of one periodic error (series and spline).
pub(super) fn is_series(group: &str) -> bool {
    group.starts_with(SERIES)
}

/// One tested reading of a periodic error: whether it is a Fourier series, the columns it adds
/// and the residual sum of squares with it.
#[derive(Debug, Clone)]
pub(super) struct Reading {
    pub fourier: bool,
    pub columns: usize,
    pub rss: f64,
    pub bic: f64,
}

/// Which reading of one periodic error the data support: the Fourier series grows one
/// harmonic at a time while the added harmonic is significant by a partial F-test at `alpha`
/// shared among the harmonics tested
/// (against the series without it, on `rows` rows beside `base_rank` base columns); the periodic
/// spline replaces it only where its BIC is lower (a shape the harmonics do not follow).
pub(super) fn choose(
    readings: &[Reading],
    rows: f64,
    base_rank: usize,
    alpha: f64,
) -> Option<usize> {
    let mut series: Vec<usize> = (0..readings.len())
        .filter(|&i| readings[i].fourier)
        .collect();
    series.sort_by_key(|&i| readings[i].columns);
    let mut chosen = series.first().copied();
    // Each further harmonic is one more test of the same effect: Bonferroni over them.
    let level = alpha / series.len().saturating_sub(1).max(1) as f64;
    for pair in series.windows(2) {
        let (a, b) = (&readings[pair[0]], &readings[pair[1]]);
        let q = b.columns.saturating_sub(a.columns) as f64;
        let dof = rows - (base_rank + b.columns) as f64;
        if q <= 0.0 || dof <= 0.0 || b.rss <= 0.0 {
            break;
        }
        let f = ((a.rss - b.rss) / q) / (b.rss / dof);
        let p = kin_estimate::statistics::f_p(f, q, dof).unwrap_or(1.0);
        if p >= level {
            break;
        }
        chosen = Some(pair[1]);
    }
    let spline = (0..readings.len())
        .filter(|&i| !readings[i].fourier)
        .min_by(|&i, &j| readings[i].bic.total_cmp(&readings[j].bic));
    match (chosen, spline) {
        (Some(c), Some(s)) if readings[s].bic < readings[c].bic => Some(s),
        (None, s) => s,
        (c, _) => c,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(fourier: bool, columns: usize, rss: f64) -> Reading {
        let (rows, rss0) = (1000.0, 100.0);
        Reading {
            fourier,
            columns,
            rss,
            bic: rows * (rss / rss0).ln() + columns as f64 * rows.ln(),
        }
    }

    #[test]
    fn harmonics_are_added_while_each_is_significant() {
        // H = 1 explains most, H = 2 a clear second harmonic, H = 3 only noise.
        let series = [
            reading(true, 2, 20.0),
            reading(true, 4, 10.0),
            reading(true, 6, 9.99),
        ];
        assert_eq!(choose(&series, 1000.0, 5, 0.01), Some(1));
        // A spline that fits no better with more columns is not preferred.
        let mut with_spline = series.to_vec();
        with_spline.push(reading(false, 2, 15.0));
        assert_eq!(choose(&with_spline, 1000.0, 5, 0.01), Some(1));
        // One that fits far better (a shape no few harmonics follow) is.
        with_spline.push(reading(false, 2, 5.0));
        assert_eq!(choose(&with_spline, 1000.0, 5, 0.01), Some(4));
    }

    #[test]
    fn a_positioning_error_is_looked_for_in_the_carriage_tilts() {
        assert_eq!(companions("X.tx"), ["X.ry", "X.rz"]);
        assert_eq!(companions("ram.tz"), ["ram.rx", "ram.ry"]);
        assert!(companions("X.rz").is_empty());
    }

    #[test]
    fn the_top_harmonic_is_found_in_a_line() {
        let line = "X.tx += fourier(X, harmonics 1..3, wavelength fit 20 mm)";
        let (h, at) = top_harmonic(line).expect("a series");
        assert_eq!((h, &line[at]), (3, "3"));
        assert_eq!(
            top_harmonic("X.tx += fourier(X, harmonics 1, wavelength fit 20 mm)"),
            None
        );
        assert_eq!(
            top_harmonic("X.tx += periodic(X, wavelength fit 20 mm, knots 2)"),
            None
        );
    }
}
