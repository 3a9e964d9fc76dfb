//! The significance tests of the fit, the diagnosis and the standard tests: one implementation
//! of each tail probability and of the lack-of-fit test.
//!
//! Every p-value is an upper tail computed by the distribution's survival function, not as
//! `1 − cdf`: where the statistic is far in the tail `1 − cdf` rounds to 0 and two tests that
//! both "fail" could not be ranked.

use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor, Normal};

/// Above this many denominator degrees of freedom an F-test uses its χ² limit: `q·F(q, d)` is
/// χ²(q) to within O(1/d), and statrs's F distribution, which goes through the incomplete beta
/// function, slows with d (minutes at 10⁷).
const F_AS_CHI_SQUARED: f64 = 1e5;

/// `P(X ≥ statistic)` for X χ²-distributed on `dof` degrees of freedom (`dof` may be
/// fractional); `None` when `dof` is not positive or either number is not finite.
pub fn chi_squared_p(statistic: f64, dof: f64) -> Option<f64> {
    if !statistic.is_finite() {
        return None;
    }
    ChiSquared::new(dof).ok().map(|d| d.sf(statistic))
}

/// `P(X ≥ f)` for X F-distributed on `(d1, d2)` degrees of freedom, through its χ²(d1) limit
/// beyond `F_AS_CHI_SQUARED` denominator degrees of freedom; a negative `f` (a rounding
/// artefact of a difference of sums of squares) counts as 0. `None` when a degree of freedom
/// is not positive or `f` is not finite.
pub fn f_p(f: f64, d1: f64, d2: f64) -> Option<f64> {
    if !f.is_finite() {
        return None;
    }
    let f = f.max(0.0);
    if d2 > F_AS_CHI_SQUARED {
        chi_squared_p(f * d1, d1)
    } else {
        FisherSnedecor::new(d1, d2).ok().map(|d| d.sf(f))
    }
}

/// `P(|Z| ≥ |z|)` for a standard normal Z: the two-sided p-value of a z statistic; `None` when
/// `z` is not finite.
pub fn normal_two_sided_p(z: f64) -> Option<f64> {
    if !z.is_finite() {
        return None;
    }
    Normal::new(0.0, 1.0).ok().map(|d| 2.0 * d.sf(z.abs()))
}

/// The classic lack-of-fit F-test: rows at identical axis positions, directions and inputs
/// (in one file, one component) scatter by the instrument alone (pure error); the rest of the
/// residual sum of squares is lack of fit.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LackOfFit {
    /// Groups of repeated poses and the rows in them.
    pub groups: usize,
    pub rows: usize,
    pub dof_pure: f64,
    pub dof_lack: f64,
    /// √(pure-error sum of squares / its dof), error unit: a model-free noise estimate.
    pub sigma_pure: f64,
    pub f: f64,
    pub p: f64,
    pub consistent: bool,
}

/// The pure-error lack-of-fit F-test. `groups` holds, for each set of replicated rows, (rows,
/// Σr, Σr²) of their residuals (groups of one row are passed over); `rss` is the residual sum
/// of squares of all `rows` residuals the test covers, of which the fit took
/// `rows − residual_dof` degrees of freedom (none when the prediction is independent of them).
/// The scatter within groups is pure error; the rest of `rss` is lack of fit. `None` when either
/// part has no degree of freedom or the replicates agree exactly.
pub fn lack_of_fit(
    groups: impl Iterator<Item = (usize, f64, f64)>,
    rss: f64,
    residual_dof: f64,
    alpha: f64,
) -> Option<LackOfFit> {
    let repeated: Vec<(usize, f64, f64)> = groups.filter(|g| g.0 > 1).collect();
    let dof_pure: f64 = repeated.iter().map(|g| (g.0 - 1) as f64).sum();
    let ss_pure: f64 = repeated
        .iter()
        .map(|g| (g.2 - g.1 * g.1 / g.0 as f64).max(0.0))
        .sum();
    let dof_lack = residual_dof - dof_pure;
    (dof_pure >= 1.0 && dof_lack >= 1.0 && ss_pure > 0.0).then(|| {
        let f = ((rss - ss_pure).max(0.0) / dof_lack) / (ss_pure / dof_pure);
        let p = f_p(f, dof_lack, dof_pure).unwrap_or(0.0);
        LackOfFit {
            groups: repeated.len(),
            rows: repeated.iter().map(|g| g.0).sum(),
            dof_pure,
            dof_lack,
            sigma_pure: (ss_pure / dof_pure).sqrt(),
            f,
            p,
            consistent: p >= alpha,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tails_match_known_quantiles() {
        // χ²(3) at its 95 % quantile 7.8147; F(2, 10) at its 95 % quantile 4.1028.
        assert!((chi_squared_p(7.814_727_903, 3.0).unwrap() - 0.05).abs() < 1e-9);
        assert!((f_p(4.102_821_015, 2.0, 10.0).unwrap() - 0.05).abs() < 1e-9);
        // Far in the tail the survival function still tells two failures apart.
        let (a, b) = (
            chi_squared_p(400.0, 10.0).unwrap(),
            chi_squared_p(500.0, 10.0).unwrap(),
        );
        assert!(a > 0.0 && b > 0.0 && b < a, "{a} {b}");
        assert_eq!(chi_squared_p(1.0, 0.0), None);
        assert_eq!(f_p(f64::NAN, 1.0, 1.0), None);
    }

    #[test]
    fn the_f_test_beyond_its_limit_is_its_chi_squared_limit() {
        let (q, d) = (3.0, 2e5);
        let near = FisherSnedecor::new(q, d).unwrap().sf(2.5);
        let limit = f_p(2.5, q, d).unwrap();
        assert!((near - limit).abs() < 1e-4, "{near} {limit}");
    }

    #[test]
    fn lack_of_fit_splits_pure_error_from_the_rest() {
        // Two groups of three replicates, residuals 1, 2, 3 and −1, 0, 1: pure-error SS 2 + 2.
        let groups = [(3usize, 6.0, 14.0), (3, 0.0, 2.0), (1, 5.0, 25.0)];
        let rss = 14.0 + 2.0 + 25.0;
        let l = lack_of_fit(groups.into_iter(), rss, 6.0, 0.05).expect("a test");
        assert_eq!((l.groups, l.rows), (2, 6));
        assert_eq!((l.dof_pure, l.dof_lack), (4.0, 2.0));
        assert!((l.sigma_pure - 1.0).abs() < 1e-12);
        assert!((l.f - ((rss - 4.0) / 2.0) / 1.0).abs() < 1e-12);
    }
}
