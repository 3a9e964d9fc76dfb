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
        if lambda > 0.0
            && lambda < axis.range[1] - axis.range[0]
            && sampled.is_some_and(|s| s.resolves(lambda))
        {
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
                    "a periodic error of wavelength ≈ {} along {}: a leadscrew pitch, a scale or encoder period",
                    fmt_len(lambda),
                    axis.name
                ),
                None,
            );
        }
    }
}
