//! A trend over time in one component's residuals: a drift or a warm-up the model lacks shows
//! as a level or a spread of the residuals that changes from one part of the measurement's
//! time to another (thesis §3.4.4). Where it does, "where the model fails" names the trend, not
//! the whole workspace, and a residual is judged an outlier against its own stretch of time:
//! the first points of a warm-up are the trend, not outliers.

use kin_estimate::statistics;

/// One residual of a component, at its time (display units) and its pose's axis positions
/// (each normalised to −1 … 1 over the data).
#[derive(Debug, Clone)]
pub(crate) struct Timed {
    pub time: f64,
    pub residual: f64,
    pub leverage: f64,
    pub x: Vec<f64>,
}

/// The residuals of one component in equal parts of the measurement's time, each part with a
/// level and a slope along every axis of its own.
#[derive(Debug, Clone)]
pub(crate) struct Trend {
    pub lo: f64,
    pub width: f64,
    pub bins: Vec<TimeBin>,
    /// The test that the parts differ (their own levels and slopes against one for all).
    pub p: f64,
    /// The RMS of the residuals over that of what is left after each part's own level and
    /// slopes: how much of the residual the trend is.
    pub ratio: f64,
}

#[derive(Debug, Clone, Default)]
pub(crate) struct TimeBin {
    pub rows: usize,
    pub mean: f64,
    /// RMS about zero.
    pub rms: f64,
    /// The part's own level and slopes (`[level, slope per axis…]`), when it has rows enough.
    pub local: Option<Vec<f64>>,
    /// The scatter about them.
    pub spread: f64,
}

/// A part needs this many rows more than its level and slopes to be judged.
const LEAST_PER_BIN: usize = 5;

/// A trend is named when it is at least this share of the residual RMS (the residuals' RMS over
/// what is left after it at least `1 + MATERIAL`): a significant but tiny change in time says
/// nothing about the model.
const MATERIAL: f64 = 0.05;

impl Trend {
    /// The bin of a time, clamped to the ends.
    pub fn bin(&self, t: f64) -> usize {
        let b = ((t - self.lo) / self.width).floor();
        (b.max(0.0) as usize).min(self.bins.len().saturating_sub(1))
    }

    /// Whether the trend is a statement at level `alpha` (Bonferroni already applied).
    pub fn significant(&self, alpha: f64) -> bool {
        self.p < alpha && self.ratio > 1.0 + MATERIAL
    }
}

/// Least squares of `y` on the columns `[1, x…]` through the normal equations (at most a few
/// axes plus one: tiny and well scaled, `x` in −1 … 1); the coefficients and the residual sum
/// of squares. `None` when singular.
fn local_fit(rows: &[&Timed], width: usize) -> Option<(Vec<f64>, f64)> {
    let k = width + 1;
    let mut a = vec![0.0; k * k];
    let mut b = vec![0.0; k];
    let row = |t: &Timed| -> Vec<f64> {
        std::iter::once(1.0)
            .chain((0..width).map(|j| t.x.get(j).copied().unwrap_or(0.0)))
            .collect()
    };
    for t in rows {
        let z = row(t);
        for i in 0..k {
            b[i] += z[i] * t.residual;
            for j in 0..k {
                a[i * k + j] += z[i] * z[j];
            }
        }
    }
    // Gaussian elimination with partial pivoting.
    let mut sol = b.clone();
    let mut m = a.clone();
    for c in 0..k {
        let p = (c..k).max_by(|&i, &j| m[i * k + c].abs().total_cmp(&m[j * k + c].abs()))?;
        if m[p * k + c].abs() <= 1e-12 * (1.0 + a[c * k + c].abs()) {
            return None;
        }
        for j in 0..k {
            m.swap(c * k + j, p * k + j);
        }
        sol.swap(c, p);
        for i in c + 1..k {
            let f = m[i * k + c] / m[c * k + c];
            for j in c..k {
                m[i * k + j] -= f * m[c * k + j];
            }
            sol[i] -= f * sol[c];
        }
    }
    for c in (0..k).rev() {
        let s: f64 = (c + 1..k).map(|j| m[c * k + j] * sol[j]).sum();
        sol[c] = (sol[c] - s) / m[c * k + c];
    }
    let rss = rows
        .iter()
        .map(|t| {
            let f: f64 = row(t).iter().zip(&sol).map(|(z, c)| z * c).sum();
            (t.residual - f).powi(2)
        })
        .sum();
    Some((sol, rss))
}

/// The residuals of one component cut in `bins` equal parts of their time, and the test that
/// the parts differ: one level and one slope along each axis for all of them (the null) against
/// a level and slopes of each part's own (an F-test on the drop of the residual sum of squares).
/// A drift of a level shows as levels that change from part to part, a scale that drifts (time
/// × position) as slopes that do, a warm-up as the first parts unlike the rest. `None` without
/// time or with too few rows.
pub(crate) fn trend(rows: &[Timed], bins: usize) -> Option<Trend> {
    let width = rows.iter().map(|r| r.x.len()).max().unwrap_or(0);
    let per = width + 1 + LEAST_PER_BIN;
    let times = rows.iter().map(|r| r.time).filter(|t| t.is_finite());
    let (lo, hi) = times.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| {
        (a.min(t), b.max(t))
    });
    if bins < 2 || !(hi > lo) || rows.len() < bins * per {
        return None;
    }
    let mut t = Trend {
        lo,
        width: (hi - lo) / bins as f64,
        bins: vec![TimeBin::default(); bins],
        p: 1.0,
        ratio: 1.0,
    };
    let mut parts: Vec<Vec<&Timed>> = vec![Vec::new(); bins];
    for r in rows.iter().filter(|r| r.time.is_finite()) {
        if let Some(p) = parts.get_mut(t.bin(r.time)) {
            p.push(r);
        }
    }
    let (mut rss1, mut n1, mut used) = (0.0, 0usize, 0usize);
    for (b, part) in t.bins.iter_mut().zip(&parts) {
        let n = part.len();
        if n == 0 {
            continue;
        }
        let nf = n as f64;
        b.rows = n;
        b.mean = part.iter().map(|r| r.residual).sum::<f64>() / nf;
        b.rms = (part.iter().map(|r| r.residual * r.residual).sum::<f64>() / nf).sqrt();
        if n < per {
            continue;
        }
        if let Some((coef, rss)) = local_fit(part, width) {
            b.spread = (rss / (n - width - 1) as f64).sqrt();
            b.local = Some(coef);
            rss1 += rss;
            n1 += n;
            used += 1;
        }
    }
    if used < 2 {
        return None;
    }
    // The parts left out (too few rows) keep the null's share: only the parts fitted are tested.
    let left: Vec<&Timed> = parts
        .iter()
        .zip(&t.bins)
        .filter(|(_, b)| b.local.is_some())
        .flat_map(|(p, _)| p.iter().copied())
        .collect();
    let (_, rss0_used) = local_fit(&left, width)?;
    let d1 = ((used - 1) * (width + 1)) as f64;
    let d2 = (n1 - used * (width + 1)) as f64;
    if d2 < 1.0 || !(rss1 > 0.0) {
        return None;
    }
    let f = ((rss0_used - rss1).max(0.0) / d1) / (rss1 / d2);
    t.p = statistics::f_p(f, d1, d2).unwrap_or(1.0);
    t.ratio = (rss0_used / rss1).sqrt();
    Some(t)
}

/// Whether a residual is an outlier against its own stretch of time: its distance from its
/// part's own level and slopes over the part's scatter, studentized by its leverage, beyond
/// `threshold`. The rows of a warm-up are judged against the warm-up's own level and scatter,
/// so only a residual far from its neighbours in time is flagged.
pub(crate) fn outlier(trend: &Trend, r: &Timed, threshold: f64) -> bool {
    let Some(b) = trend.bins.get(trend.bin(r.time)) else {
        return false;
    };
    let Some(local) = &b.local else {
        return false;
    };
    if !(b.spread > 0.0) {
        return false;
    }
    let fitted: f64 = local
        .iter()
        .enumerate()
        .map(|(j, c)| {
            c * if j == 0 {
                1.0
            } else {
                r.x.get(j - 1).copied().unwrap_or(0.0)
            }
        })
        .sum();
    let z = (r.residual - fitted) / (b.spread * (1.0 - r.leverage).max(1e-9).sqrt());
    z.abs() > threshold
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn noise(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        // A sum of twelve uniforms: near normal, unit variance.
        (0..n)
            .map(|_| (0..12).map(|_| rng.random_range(0.0..1.0)).sum::<f64>() - 6.0)
            .collect()
    }

    fn rows(f: impl Fn(f64, f64) -> f64, n: usize, seed: u64) -> Vec<Timed> {
        noise(n, seed)
            .into_iter()
            .enumerate()
            .map(|(i, e)| {
                let t = 360.0 * i as f64 / n as f64;
                // One axis, swept back and forth every 20 rows.
                let x = ((i % 20) as f64 / 9.5) - 1.0;
                Timed {
                    time: t,
                    residual: 0.2 * e + f(t, x),
                    leverage: 0.01,
                    x: vec![x],
                }
            })
            .collect()
    }

    #[test]
    fn noise_alone_is_no_trend() {
        let alpha = 0.01 / 30.0;
        let named = (0..40)
            .filter(|&s| trend(&rows(|_, _| 0.0, 500, s), 8).is_some_and(|t| t.significant(alpha)))
            .count();
        assert_eq!(named, 0);
    }

    #[test]
    fn a_drift_and_a_warm_up_are_trends() {
        let alpha = 0.01 / 30.0;
        // A level that moves by 1 (five times the noise) over the time.
        let drift = trend(&rows(|t, _| (t - 180.0) / 180.0, 500, 1), 8).expect("bins");
        assert!(drift.significant(alpha), "{drift:?}");
        // A slope along the axis that grows in time (a scale drift), ±0.5 at the ends: the
        // level of every part stays at zero.
        let scale = trend(&rows(|t, x| 0.5 * x * (t - 180.0) / 180.0, 500, 4), 8).expect("bins");
        assert!(scale.significant(alpha), "{scale:?}");
        // A warm-up with τ = 30 min: the first hour is off, the rest settled.
        let warm = trend(&rows(|t, _| -(-t / 30.0f64).exp(), 500, 2), 8).expect("bins");
        assert!(warm.significant(alpha), "{warm:?}");
        // Its first rows are the trend, judged against their own bin: none is an outlier.
        let all = rows(|t, _| -(-t / 30.0f64).exp(), 500, 2);
        let flagged = all.iter().filter(|r| outlier(&warm, r, 4.0)).count();
        assert_eq!(flagged, 0);
    }

    #[test]
    fn a_gross_error_stays_an_outlier_after_the_trend() {
        let mut all = rows(|t, _| -(-t / 30.0f64).exp(), 500, 3);
        all[300].residual += 3.0;
        let t = trend(&all, 8).expect("bins");
        assert!(outlier(&t, &all[300], 4.0));
    }
}
