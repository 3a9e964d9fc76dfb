//! Thermal candidates beyond a temperature's single lag: the heat sources a model declares as
//! inputs (a spindle's speed, a feed, a power) through a lag, and a second time constant (a lag
//! of a lag: a slow structure warmed by a faster one) where the model already follows that
//! input with a lag in that component. A two-stage lag is never proposed in place of a first
//! one: with its fast stage at zero it is the single lag, so the data could not prefer it, and
//! the simpler form comes first. Each competes in the group of its target and input with the
//! single lags of [`super::library`], so the data pick one time constant per effect.

use kin_compiler::ir::{Component, FrameRef, Machine, Scalar, Var};
use kin_compiler::units::Dim;

use super::library::{push, round, Available, Proposal, Term};
use super::Family;

/// The reference value a heat source is divided by, so that its coefficient reads as the
/// drift at a round operating point (`um` at 1000 rpm held long).
fn reference(dim: Dim) -> Option<&'static str> {
    match dim {
        d if d == Dim::SPEED => Some("1000 rpm"),
        d if d == Dim::VELOCITY => Some("1000 mm/min"),
        d if d == Dim::POWER => Some("1 kW"),
        _ => None,
    }
}

/// Whether the tool's `comp` already has a term scaled by a lag of input `input`.
fn has_lag_of(m: &Machine, comp: Component, input: usize) -> bool {
    fn lagged(s: &Scalar, m: &Machine, input: usize) -> bool {
        match s {
            Scalar::Var(Var::Lag(l)) => m
                .lags
                .get(*l)
                .is_some_and(|l| !l.warmup && l.input == input),
            Scalar::Num(_) | Scalar::Var(_) => false,
            Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => lagged(a, m, input),
            Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
                lagged(a, m, input) || lagged(b, m, input)
            }
        }
    }
    m.errors
        .iter()
        .filter(|e| e.frame == FrameRef::ToolEnd(None) && e.component == comp)
        .flat_map(|e| &e.terms)
        .any(|t| lagged(&t.scale, m, input))
}

/// Appends the heat-source and two-stage lag candidates on the tool's translations (the
/// growth of a spindle or ram), for inputs every file carries, when the data have `time`.
pub(super) fn propose(m: &Machine, available: &Available, taus: &[f64], out: &mut Vec<Proposal>) {
    if !available.time {
        return;
    }
    let minutes = |tau: f64| format!("{} min", round(tau / 60.0));
    for (i, input) in m.inputs.iter().enumerate() {
        if !available.inputs.get(i).copied().unwrap_or(false) {
            continue;
        }
        let source = match reference(input.unit.dim) {
            Some(r) => format!("{} / {r}", input.name),
            None if input.unit.dim == Dim::TEMPERATURE && !input.absolute => input.name.clone(),
            None => continue,
        };
        let heat_source = input.unit.dim != Dim::TEMPERATURE;
        for comp in [Component::Tx, Component::Ty, Component::Tz] {
            let target = format!("tool.{}", comp.name());
            let group = Some(format!("thermal {target} {}", input.name));
            if heat_source {
                for &tau in taus {
                    let t = minutes(tau);
                    push(
                        out,
                        Family::Thermal,
                        target.clone(),
                        vec![Term {
                            text: format!("lag({source}, tau fit {t}) * const"),
                            test: format!("lag({source}, tau {t}) * const"),
                            harmonic: None,
                        }],
                        format!(
                            "{target} follows the heat of {} through a thermal lag (time constant ≈ {t})",
                            input.name
                        ),
                        group.clone(),
                    );
                }
            }
            // Two stages: every pair of scanned time constants, the faster first, where one
            // stage is already in the model.
            if !has_lag_of(m, comp, i) {
                continue;
            }
            for (k, &fast) in taus.iter().enumerate() {
                for &slow in taus.iter().skip(k + 1) {
                    let (t1, t2) = (minutes(fast.min(slow)), minutes(fast.max(slow)));
                    push(
                        out,
                        Family::Thermal,
                        target.clone(),
                        vec![Term {
                            text: format!(
                                "lag(lag({source}, tau fit {t1}), tau fit {t2}) * const"
                            ),
                            test: format!("lag(lag({source}, tau {t1}), tau {t2}) * const"),
                            harmonic: None,
                        }],
                        format!(
                            "{target} follows {} through two thermal lags in series (≈ {t1}, then ≈ {t2})",
                            input.name
                        ),
                        group.clone(),
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SRC: &str = r#"
machine spindle {
    task position
    units { length mm, angle deg, error um, tilt urad, time min }
    axis Z prismatic along z range -300 mm .. 0 mm
    input S : speed
    input T : temperature rise
    input T_abs : temperature absolute
    tool chain {
        Z moving
        tool t at (0, 0, -100) mm
    }
    errors {
        Z.tz = linear(Z) + (T_abs - 20 degC) * const
        tool.tx = lag(T, tau fit 20 min) * const
        tool.ty = lag(S / 1000 rpm, tau fit 20 min) * const
    }
}
"#;

    fn machine(src: &str) -> Machine {
        let out = kin_compiler::compile(src);
        match out.compiled {
            Some(c) => c.machine,
            None => panic!("{:?}", out.diagnostics),
        }
    }

    fn available(m: &Machine, time: bool) -> Available {
        Available {
            directions: vec![true; m.axes.len()],
            inputs: vec![true; m.inputs.len()],
            time,
            sampled: vec![None; m.axes.len()],
            reversals: Vec::new(),
        }
    }

    #[test]
    fn heat_sources_and_second_stages_are_proposed_and_compile() {
        let m = machine(SRC);
        let mut out = Vec::new();
        propose(&m, &available(&m, true), &[600.0, 5400.0], &mut out);
        let texts: Vec<&str> = out.iter().map(|p| p.candidate.text.as_str()).collect();
        assert!(
            texts.contains(&"tool.tz += lag(S / 1000 rpm, tau fit 10 min) * const"),
            "{texts:#?}"
        );
        assert!(
            texts.contains(&"tool.tx += lag(lag(T, tau fit 10 min), tau fit 90 min) * const"),
            "{texts:#?}"
        );
        assert!(texts.contains(
            &"tool.ty += lag(lag(S / 1000 rpm, tau fit 10 min), tau fit 90 min) * const"
        ));
        // No lag of an absolute temperature (it has an arbitrary zero); second stages only where
        // a first is: 3 targets × 2 single lags of S, one pair for S (tool.ty), one for T
        // (tool.tx).
        assert!(texts.iter().all(|t| !t.contains("T_abs")));
        assert!(!texts.iter().any(|t| t.starts_with("tool.tz += lag(lag(")));
        assert_eq!(out.len(), 6 + 2);
        // Each candidate, added to the model, checks clean.
        for p in &out {
            let last = "        tool.ty = lag(S / 1000 rpm, tau fit 20 min) * const\n";
            let src = SRC.replace(last, &format!("{last}        {}\n", p.test_text));
            assert_ne!(src, SRC);
            let c = kin_compiler::compile(&src);
            assert!(c.compiled.is_some(), "{}: {:?}", p.test_text, c.diagnostics);
        }
    }

    #[test]
    fn without_time_nothing_is_proposed() {
        let m = machine(SRC);
        let mut out = Vec::new();
        propose(&m, &available(&m, false), &[600.0, 5400.0], &mut out);
        assert!(out.is_empty());
    }
}
