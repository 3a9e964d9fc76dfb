//! Candidates for periodic errors along a prismatic axis (a leadscrew's pitch, a scale or
//! encoder period; thesis eq. 3.11–3.15), at the wavelengths the residual spectra show.

use kin_compiler::ir::{Axis, Machine};

use super::library::{push, round, Available, Proposal, Term};
use super::Family;

/// Appends the periodic candidates for the prismatic axis `a` (`name` its frame's name,
/// `target` the error component along its motion) at each spectral peak found for it.
pub(super) fn propose(
    out: &mut Vec<Proposal>,
    m: &Machine,
    available: &Available,
    wavelengths: &[(usize, f64)],
    a: usize,
    axis: &Axis,
    target: &str,
) {
    let length = &m.units.length;
    let fmt_len = |v: f64| format!("{} {}", round(length.from_si(v)), length.name);
    let sampled = available.sampled.get(a).copied().flatten();
    for &(_, lambda) in wavelengths.iter().filter(|(pa, _)| *pa == a) {
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
            let harmonics = match top {
                1 => "a sinusoid".to_string(),
                2 => "a sinusoid and its 2nd harmonic".to_string(),
                3 => "a sinusoid and its 2nd and 3rd harmonics".to_string(),
                _ => format!("a sinusoid and its harmonics up to the {top}th"),
            };
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
                        fmt_len(lambda)
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
                    fmt_len(lambda)
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
    }
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
pub(super) struct Reading {
    pub fourier: bool,
    pub columns: usize,
    pub rss: f64,
    pub bic: f64,
}

/// Which reading of one periodic error the data support: the Fourier series grows one
/// harmonic at a time while the added harmonic is significant by a partial F-test at `alpha`
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
    for pair in series.windows(2) {
        let (a, b) = (&readings[pair[0]], &readings[pair[1]]);
        let q = b.columns.saturating_sub(a.columns) as f64;
        let dof = rows - (base_rank + b.columns) as f64;
        if q <= 0.0 || dof <= 0.0 || b.rss <= 0.0 {
            break;
        }
        let f = ((a.rss - b.rss) / q) / (b.rss / dof);
        let p = statrs::distribution::FisherSnedecor::new(q, dof)
            .map(|d| 1.0 - statrs::distribution::ContinuousCDF::cdf(&d, f.max(0.0)))
            .unwrap_or(1.0);
        if p >= alpha {
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
