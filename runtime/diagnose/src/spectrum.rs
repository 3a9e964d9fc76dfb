//! The residual spectra along the prismatic axes: the Lomb–Scargle periodogram (Scargle 1982)
//! for the non-uniform sampling real measurement plans have.
//!
//! The cost is wavelengths × positions, for every axis and component; two exact reductions keep
//! it down at scale. The rows are grouped by their position along the axis (the same bits), so
//! a component's rows at one position are one term weighted by their count, and the components
//! (`ex`, `ey`, `ez` of one pose share its position) share one `sin`/`cos` per position. And the
//! periodogram's time shift τ is applied to five sums after the pass (the rotation below), not
//! to every point in a second one: one pass over the positions per wavelength, four at a time.
//! The wavelengths are independent: they are split over the threads in fixed ranges, so the
//! powers do not depend on the number of threads.

use super::library::Sampling;

/// The least number of rows of a component for a spectrum of it.
const MIN_ROWS: usize = 30;
/// Wavelengths per spectrum (log-spaced, ~1 % apart).
const COUNT: usize = 600;

/// The rows of one axis, grouped by position: per position its value and, per component, the
/// number of rows there and the sum of their residuals less the component's mean.
pub(super) struct Positions {
    x: Vec<f64>,
    /// Per component (of the `components` order given to [`Positions::group`]): count and
    /// centred residual sum per position.
    count: Vec<Vec<f64>>,
    sum: Vec<Vec<f64>>,
}

/// One component's rows along an axis and the variance of their residuals.
#[derive(Debug, Clone, Copy)]
pub(super) struct Moments {
    pub rows: usize,
    pub var: f64,
}

impl Positions {
    /// Groups `rows` — (component slot, position, residual), positions finite — for
    /// `components` slots; also returns each slot's moments (the mean and variance over its
    /// rows in the order given, as the periodogram centres and normalises by them).
    pub fn group(
        components: usize,
        rows: impl Iterator<Item = (usize, f64, f64)> + Clone,
    ) -> (Positions, Vec<Moments>) {
        let mut n = vec![0usize; components];
        let mut total = vec![0.0; components];
        for (c, _, y) in rows.clone() {
            if let (Some(n), Some(t)) = (n.get_mut(c), total.get_mut(c)) {
                *n += 1;
                *t += y;
            }
        }
        let mean: Vec<f64> = (0..components)
            .map(|c| total[c] / (n[c].max(1) as f64))
            .collect();
        let mut dev = vec![0.0; components];
        let mut at: std::collections::HashMap<u64, usize> = std::collections::HashMap::new();
        let mut p = Positions {
            x: Vec::new(),
            count: vec![Vec::new(); components],
            sum: vec![Vec::new(); components],
        };
        for (c, x, y) in rows {
            if c >= components {
                continue;
            }
            let g = *at.entry(x.to_bits()).or_insert_with(|| {
                p.x.push(x);
                for k in 0..components {
                    p.count[k].push(0.0);
                    p.sum[k].push(0.0);
                }
                p.x.len() - 1
            });
            p.count[c][g] += 1.0;
            p.sum[c][g] += y - mean[c];
            dev[c] += (y - mean[c]).powi(2);
        }
        let moments = (0..components)
            .map(|c| Moments {
                rows: n[c],
                var: if n[c] > 1 {
                    dev[c] / (n[c] - 1) as f64
                } else {
                    0.0
                },
            })
            .collect();
        (p, moments)
    }

    /// The normalised periodogram of the components `which` (slots, with their variances) at
    /// angular frequency `w`, into `power` (one per component of `which`).
    fn power(&self, w: f64, which: &[(usize, f64)], power: &mut [f64]) {
        // Per component: Σn cos², Σn sin², Σn sin cos, Σỹ cos, Σỹ sin (ỹ centred).
        let mut acc = vec![[wide::f64x4::splat(0.0); 5]; which.len()];
        let g = self.x.len();
        let full = g - g % 4;
        let lanes = |v: &[f64], i: usize| wide::f64x4::new([v[i], v[i + 1], v[i + 2], v[i + 3]]);
        for i in (0..full).step_by(4) {
            let (s, c) = (lanes(&self.x, i) * w).sin_cos();
            let (cc, ss, sc) = (c * c, s * s, s * c);
            for (a, &(k, _)) in acc.iter_mut().zip(which) {
                let (n, y) = (lanes(&self.count[k], i), lanes(&self.sum[k], i));
                a[0] = n * cc + a[0];
                a[1] = n * ss + a[1];
                a[2] = n * sc + a[2];
                a[3] = y * c + a[3];
                a[4] = y * s + a[4];
            }
        }
        let mut sums: Vec<[f64; 5]> = acc
            .iter()
            .map(|a| std::array::from_fn(|j| a[j].reduce_add()))
            .collect();
        for i in full..g {
            let (s, c) = libm::sincos(w * self.x[i]);
            for (t, &(k, _)) in sums.iter_mut().zip(which) {
                let (n, y) = (self.count[k][i], self.sum[k][i]);
                t[0] += n * c * c;
                t[1] += n * s * s;
                t[2] += n * s * c;
                t[3] += y * c;
                t[4] += y * s;
            }
        }
        for ((t, &(_, var)), out) in sums.iter().zip(which).zip(power.iter_mut()) {
            let [cc, ss, sc, yc, ys] = *t;
            // τ with tan 2wτ = Σ sin 2wx / Σ cos 2wx makes the sine and cosine terms
            // orthogonal; the sums at the shifted phase wx − wτ follow from the unshifted ones
            // by the rotation through wτ.
            let (st, ct) = libm::sincos(0.5 * libm::atan2(2.0 * sc, cc - ss));
            let yc_t = yc * ct + ys * st;
            let ys_t = ys * ct - yc * st;
            let cc_t = cc * ct * ct + 2.0 * sc * ct * st + ss * st * st;
            let ss_t = ss * ct * ct - 2.0 * sc * ct * st + cc * st * st;
            // A rotated sum that is rounding only (every position at one phase) is no term.
            let tiny = 1e-12 * (cc + ss);
            *out = if cc_t > tiny && ss_t > tiny {
                (yc_t * yc_t / cc_t + ys_t * ys_t / ss_t) / (2.0 * var)
            } else {
                0.0
            };
        }
    }
}

/// One component's spectrum along an axis: wavelengths (display unit) and normalised powers,
/// the peak refined, and the peak's false-alarm probability.
pub(super) struct Computed {
    /// The component's slot.
    pub slot: usize,
    pub wavelengths: Vec<f64>,
    pub power: Vec<f64>,
    pub false_alarm: f64,
}

/// The spectra of every component slot of `positions` with at least [`MIN_ROWS`] rows and a
/// variance, along an axis of `range` (display unit) whose sampling resolves nothing below
/// `nyquist`, on `threads` threads.
pub(super) fn spectra(
    positions: &Positions,
    moments: &[Moments],
    range: f64,
    nyquist: f64,
    threads: usize,
) -> Vec<Computed> {
    // Wavelengths that repeat at least three times over the covered range, down to about four
    // samples per period and never below twice the median spacing of the distinct positions
    // (`Sampling::resolves`). The grid depends on the component's rows: components with the
    // same grid share a pass.
    let grid = |m: &Moments| -> Option<(f64, f64)> {
        if m.rows < MIN_ROWS || m.var <= 0.0 {
            return None;
        }
        let longest = range / Sampling::PERIODS;
        let shortest = (4.0 * range / m.rows as f64)
            .max(range / 2000.0)
            .max(nyquist);
        (shortest < longest).then_some((longest, shortest))
    };
    let mut out = Vec::new();
    let mut done = vec![false; moments.len()];
    for first in 0..moments.len() {
        if done[first] {
            continue;
        }
        let Some((longest, shortest)) = grid(&moments[first]) else {
            continue;
        };
        let which: Vec<(usize, f64)> = (first..moments.len())
            .filter(|&k| {
                grid(&moments[k]).is_some_and(|g| g.0 == longest && g.1 == shortest) && !done[k]
            })
            .map(|k| (k, moments[k].var))
            .collect();
        which.iter().for_each(|&(k, _)| done[k] = true);
        let wavelengths: Vec<f64> = (0..COUNT)
            .map(|k| longest * (shortest / longest).powf(k as f64 / (COUNT - 1) as f64))
            .collect();
        let powers = grid_powers(positions, &wavelengths, &which, threads);
        for (i, &(slot, var)) in which.iter().enumerate() {
            let mut wavelengths = wavelengths.clone();
            let mut power: Vec<f64> = powers.iter().map(|p| p[i]).collect();
            refine(positions, slot, var, &mut wavelengths, &mut power);
            let peak = power.iter().copied().fold(0.0, f64::max);
            let independent = independent(range, shortest);
            let fap = 1.0 - (1.0 - (-peak).exp()).powf(independent);
            out.push(Computed {
                slot,
                wavelengths,
                power,
                false_alarm: fap.clamp(0.0, 1.0),
            });
        }
    }
    out.sort_by_key(|c| c.slot);
    out
}

/// How many independent wavelengths a spectrum over `range` down to `shortest` searches: the
/// periods its shortest wavelength spans over the range (either unit, the same for both). The
/// peak's false-alarm probability and the p-value of a candidate placed at the peak count them.
pub(super) fn independent(range: f64, shortest: f64) -> f64 {
    (range / shortest).max(1.0)
}

/// The powers at every wavelength (row) for the components `which` (column), the wavelengths
/// split in fixed contiguous ranges over `threads` threads.
fn grid_powers(
    positions: &Positions,
    wavelengths: &[f64],
    which: &[(usize, f64)],
    threads: usize,
) -> Vec<Vec<f64>> {
    let mut powers = vec![vec![0.0; which.len()]; wavelengths.len()];
    let run = |lambdas: &[f64], out: &mut [Vec<f64>]| {
        for (l, p) in lambdas.iter().zip(out.iter_mut()) {
            positions.power(std::f64::consts::TAU / l, which, p);
        }
    };
    // Below this many positions a thread costs more than it saves.
    let threads = if positions.x.len() < 2000 {
        1
    } else {
        threads.max(1)
    };
    let chunk = wavelengths.len().div_ceil(threads).max(1);
    if threads == 1 {
        run(wavelengths, &mut powers);
    } else {
        std::thread::scope(|s| {
            for (l, p) in wavelengths.chunks(chunk).zip(powers.chunks_mut(chunk)) {
                s.spawn(move || run(l, p));
            }
        });
    }
    powers
}

/// The grid is ~1 % apart, but over tens of periods a wavelength off by that much drifts out of
/// phase, and a candidate tested at it needs spurious harmonics to follow: the peak moves to
/// the maximum between its neighbours (golden section).
fn refine(
    positions: &Positions,
    slot: usize,
    var: f64,
    wavelengths: &mut [f64],
    power: &mut [f64],
) {
    let count = power.len();
    let Some(k) = (1..count.saturating_sub(1))
        .max_by(|&a, &b| power[a].total_cmp(&power[b]))
        .filter(|&k| power[k] >= power[k - 1] && power[k] >= power[k + 1])
    else {
        return;
    };
    let at = |lambda: f64| {
        let mut p = [0.0];
        positions.power(std::f64::consts::TAU / lambda, &[(slot, var)], &mut p);
        p[0]
    };
    let (mut a, mut b) = (wavelengths[k + 1], wavelengths[k - 1]);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    // Each step keeps one inner point and its power: one new evaluation per step.
    let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
    let (mut pc, mut pd) = (at(c), at(d));
    for _ in 0..40 {
        if pc >= pd {
            b = d;
            (d, pd) = (c, pc);
            c = b - g * (b - a);
            pc = at(c);
        } else {
            a = c;
            (c, pc) = (d, pd);
            d = a + g * (b - a);
            pd = at(d);
        }
    }
    let best = 0.5 * (a + b);
    let p = at(best);
    if p > power[k] {
        wavelengths[k] = best;
        power[k] = p;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The periodogram as written in Scargle (1982): τ from the double-angle sums, then the
    /// projections at the shifted phase, one point at a time.
    fn direct(pts: &[(f64, f64)], lambda: f64) -> f64 {
        let n = pts.len() as f64;
        let mean = pts.iter().map(|p| p.1).sum::<f64>() / n;
        let var = pts.iter().map(|p| (p.1 - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let w = std::f64::consts::TAU / lambda;
        let (s2, c2) = pts.iter().fold((0.0, 0.0), |(s, c), (x, _)| {
            (s + (2.0 * w * x).sin(), c + (2.0 * w * x).cos())
        });
        let tau = s2.atan2(c2) / (2.0 * w);
        let (mut yc, mut ys, mut cc, mut ss) = (0.0, 0.0, 0.0, 0.0);
        for (x, y) in pts {
            let (s, c) = (w * (x - tau)).sin_cos();
            yc += (y - mean) * c;
            ys += (y - mean) * s;
            cc += c * c;
            ss += s * s;
        }
        (yc * yc / cc + ys * ys / ss) / (2.0 * var)
    }

    /// Grouped, rotated, four lanes and two components at once: the textbook periodogram of
    /// each component alone, with repeated positions and a remainder that is not a multiple of
    /// four; the threads change no bit.
    #[test]
    fn the_reduced_periodogram_is_scargles() {
        // Positions on a coarse grid (repeats) and off it; two components, one with a period.
        let rows: Vec<(usize, f64, f64)> = (0..403)
            .flat_map(|i| {
                let x = if i % 3 == 0 {
                    (i % 17) as f64 * 7.5
                } else {
                    1.2345 * i as f64 + 0.01 * ((i * i) % 13) as f64
                };
                let a = (std::f64::consts::TAU * x / 23.0).sin() + 0.1 * ((i * 7) % 5) as f64;
                let b = 0.3 * ((i * 11) % 7) as f64 - 0.002 * x;
                [(0, x, a), (1, x, b)]
            })
            .filter(|&(c, x, _)| !(c == 1 && x > 400.0))
            .collect();
        let (p, moments) = Positions::group(2, rows.iter().copied());
        assert!(p.x.len() < 403, "repeated positions share a group");
        for (slot, m) in moments.iter().enumerate() {
            let pts: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.0 == slot)
                .map(|r| (r.1, r.2))
                .collect();
            assert_eq!(m.rows, pts.len());
            for lambda in [400.0, 23.0, 9.7, 3.1] {
                let mut one = [0.0; 2];
                p.power(
                    std::f64::consts::TAU / lambda,
                    &[(0, moments[0].var), (1, moments[1].var)],
                    &mut one,
                );
                let want = direct(&pts, lambda);
                assert!(
                    (one[slot] - want).abs() <= 1e-10 * want.max(1.0),
                    "slot {slot} λ {lambda}: {} against {want}",
                    one[slot]
                );
            }
        }
        let one = spectra(&p, &moments, 500.0, 2.0, 1);
        let two = spectra(&p, &moments, 500.0, 2.0, 2);
        assert_eq!(one.len(), 2);
        for (a, b) in one.iter().zip(&two) {
            assert_eq!(a.power, b.power);
            assert_eq!(a.wavelengths, b.wavelengths);
        }
        // The period of slot 0 is its peak, refined to well within the grid's 1 %.
        let peak = |c: &Computed| {
            let k = (0..c.power.len())
                .max_by(|&i, &j| c.power[i].total_cmp(&c.power[j]))
                .unwrap_or(0);
            c.wavelengths[k]
        };
        assert!((peak(&one[0]) - 23.0).abs() < 0.05, "{}", peak(&one[0]));
        assert!(
            one[0].false_alarm < 1e-6 && one[0].false_alarm < one[1].false_alarm,
            "{} {}",
            one[0].false_alarm,
            one[1].false_alarm
        );
    }

    /// The four-lane sin/cos against libm's, over the arguments of a spectrum (positions of a
    /// metre in mm at wavelengths down to a tenth of a mm) and beyond.
    #[test]
    fn vectorised_sincos_matches_libm() {
        for w in [1e-3, 0.7, std::f64::consts::TAU / 0.1, 400.0] {
            for i in (0..1003).step_by(4) {
                let x: [f64; 4] = std::array::from_fn(|l| -200.0 + 1.234567 * (i + l) as f64);
                let (sn, cs) = (wide::f64x4::new(x) * w).sin_cos();
                for (l, x) in x.iter().enumerate() {
                    let (s0, c0) = libm::sincos(w * x);
                    let (s, c) = (sn.to_array()[l], cs.to_array()[l]);
                    assert!(
                        (s - s0).abs() < 1e-14 && (c - c0).abs() < 1e-14,
                        "w {w} x {x}: {s} {c} against {s0} {c0}"
                    );
                }
            }
        }
    }
}
