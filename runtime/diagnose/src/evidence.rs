//! A candidate must agree with every measured component, not only with their sum.
//!
//! The partial F-test judges a candidate by the residual sum of squares of all rows together.
//! A line can lower that sum by moving coefficients that other components need: on a
//! positioner observed as full poses, a term that bends the positions into place while turning
//! the measured rotations away from theirs wins on the total and is wrong. No physical effect
//! the model lacks does that: adding it moves the shared coefficients towards their true
//! values, which every component prefers. So the refit with the line is compared with the base
//! fit component by component (the observed ex … erz and lengths, each a sum over its own rows,
//! weighted as the fit weighs them): a component whose sum grows by more than its share of
//! the noise says the line is contradicted by the data.
//!
//! The test: with `k` columns added, a component's sum can grow by chance by about a
//! χ²(k)·σ_c² (the columns fit noise, which moves the shared coefficients; σ_c² the
//! component's own mean square in the base fit, an upper bound of its noise); growth `Δ`
//! beyond the χ²(k) quantile at `α / C` (`C` components observed, Bonferroni) is not chance.

use kin_compiler::ir::Machine;
use kin_estimate::fit::report::component_name;
use kin_estimate::fit::{FitResult, LENGTH};
use kin_estimate::statistics;

use super::analyse::display;
use super::Worse;

/// Components of a row: ex … erz and the length rows.
const COMPONENTS: usize = LENGTH as usize + 1;

/// Per component: the weighted residual sum of squares, the display-unit sum of squares
/// and the rows.
#[derive(Debug, Clone, Copy, Default)]
struct Sums {
    weighted: f64,
    shown: f64,
    rows: usize,
}

/// Each component's sums over the residuals of `r`; `None` when the fit kept only some of its
/// residuals (a streamed fit of very many rows).
fn sums(m: &Machine, r: &FitResult) -> Option<[Sums; COMPONENTS]> {
    if r.residuals.len() != r.rows {
        return None;
    }
    let mut out = [Sums::default(); COMPONENTS];
    for row in &r.residuals {
        let c = row.meta.component;
        let weights = r
            .layout
            .file_weights
            .get(row.meta.file as usize)
            .unwrap_or(&r.layout.weights);
        let s = out.get_mut(c as usize)?;
        s.weighted += row.residual * row.residual;
        let shown = display(m, weights, c, row.residual);
        s.shown += shown * shown;
        s.rows += 1;
    }
    Some(out)
}

/// The components the refit `after` (with `added` columns more than `before`) makes worse
/// beyond chance, at family-wise level `alpha` over the observed components.
pub(super) fn worse(
    m: &Machine,
    before: &FitResult,
    after: &FitResult,
    added: usize,
    alpha: f64,
) -> Vec<Worse> {
    let (Some(b), Some(a)) = (sums(m, before), sums(m, after)) else {
        return Vec::new();
    };
    if added == 0 {
        return Vec::new();
    }
    let observed = b.iter().filter(|s| s.rows > 0).count().max(1);
    let level = alpha / observed as f64;
    let mut out = Vec::new();
    for (c, (sb, sa)) in b.iter().zip(&a).enumerate() {
        if sb.rows == 0 || sb.rows != sa.rows {
            continue;
        }
        // Against the component's own scatter in the base fit: σ̂² of all rows would hold
        // the other components' misfit (the very misfit the line is offered for), and the
        // growth of a component at its noise would drown in it.
        let variance = sb.weighted / sb.rows as f64;
        if !(variance > 0.0) {
            continue;
        }
        let grown = (sa.weighted - sb.weighted) / variance;
        if !(grown > 0.0) {
            continue;
        }
        let Some(p) = statistics::chi_squared_p(grown, added as f64) else {
            continue;
        };
        if p < level {
            let c = c as u8;
            let unit = if (3..6).contains(&c) {
                &m.units.tilt
            } else {
                &m.units.error
            };
            let n = sb.rows as f64;
            out.push(Worse {
                component: component_name(c).to_string(),
                rms_before: (sb.shown / n).sqrt(),
                rms_after: (sa.shown / n).sqrt(),
                unit: unit.name.clone(),
                p,
            });
        }
    }
    out
}

/// What a finding says of the components it makes worse.
pub(super) fn said(worse: &[Worse]) -> String {
    let parts: Vec<String> = worse
        .iter()
        .map(|w| {
            format!(
                "{} RMS {} → {} {}",
                w.component,
                three(w.rms_before),
                three(w.rms_after),
                w.unit
            )
        })
        .collect();
    format!(
        "the refit makes measured components worse beyond their noise ({}): the line trades them for the others",
        parts.join(", ")
    )
}

/// Three significant digits, without an exponent for the sizes residuals have.
fn three(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    format!("{v:.digits$}")
}

#[cfg(test)]
mod tests {
    use super::{three, worse};
    use kin_compiler::{compile, Compiled};
    use kin_data::data::Observations;
    use kin_estimate::fit::{self, DataSet, FitResult};
    use kin_estimate::simulate::{self, sample_points};
    use kin_model::interp::Interpreter;

    /// An X–Z machine whose tool hangs 200 mm below the Z ram, measured as full poses.
    fn machine(errors: &str) -> Compiled {
        let src = format!(
            "machine xz {{
                task measure
                units {{ length mm, error um, tilt urad }}
                axis X prismatic along x range 0 mm .. 500 mm
                axis Z prismatic along z range -300 mm .. 0 mm
                tool chain {{
                    X moving
                    Z moving at (0, 0, 400) mm
                    tool probe at (0, 0, -200) mm
                }}
                errors {{
                    {errors}
                }}
            }}"
        );
        let out = compile(&src);
        out.compiled
            .unwrap_or_else(|| panic!("{src}\n{:#?}", out.diagnostics))
    }

    fn fitted(errors: &str, files: &[DataSet]) -> (Compiled, FitResult) {
        let c = machine(errors);
        let mut it = Interpreter::new(&c.machine).expect("interpreter");
        let r = fit::fit(
            &c,
            &mut it,
            files,
            &[],
            &fit::Options::default(),
            &mut |_, _| {},
        )
        .expect("fit");
        (c, r)
    }

    /// X's positioning error is a pure translation (a scale error); its rotations are measured
    /// and show nothing. A pitch of X seen through the 200 mm arm bends the positions towards
    /// it but predicts pitch the rotations do not have: contradicted. The scale error itself
    /// is not.
    #[test]
    fn a_line_that_trades_rotations_for_positions_is_contradicted() {
        let truth = machine("X.tx = linear(X)\n Z.tz = linear(Z)");
        let beta = [20e-6, 2e-6];
        let poses = sample_points(&truth.machine, 400, 7);
        let obs = simulate::simulate(
            &truth.machine,
            &beta,
            &Observations::Points(poses),
            &simulate::Options {
                observe: [true; 6],
                noise: 0.5e-6,
                noise_tilt: 0.5e-6,
                seed: 8,
                ..simulate::Options::default()
            },
        )
        .expect("simulate");
        let files = [DataSet {
            path: "poses.csv".into(),
            observations: obs,
        }];
        let base_errors = "X.tx = const\n Z.tz = linear(Z)";
        let (_, base) = fitted(base_errors, &files);
        let (wrong, pitch) = fitted(&format!("{base_errors}\n X.ry += linear(X)"), &files);
        let pitch_worse = worse(&wrong.machine, &base, &pitch, 1, 0.01);
        assert!(
            pitch.solution.rss < base.solution.rss,
            "the pitch lowers the total"
        );
        assert_eq!(
            pitch_worse
                .iter()
                .map(|w| w.component.as_str())
                .collect::<Vec<_>>(),
            ["ery"],
            "{pitch_worse:?}"
        );
        let w = &pitch_worse[0];
        assert!(w.rms_after > 1.3 * w.rms_before, "{w:?}");
        let (right, scale) = fitted(&format!("{base_errors}\n X.tx += linear(X)"), &files);
        let scale_worse = worse(&right.machine, &base, &scale, 1, 0.01);
        assert!(scale_worse.is_empty(), "{scale_worse:?}");
    }

    #[test]
    fn three_digits() {
        assert_eq!(three(414.23), "414");
        assert_eq!(three(5.4123), "5.41");
        assert_eq!(three(0.012345), "0.0123");
        assert_eq!(three(12345.0), "12345");
    }
}
