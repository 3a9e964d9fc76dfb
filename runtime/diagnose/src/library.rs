//! The library of candidate physical effects: terms a model may lack, generated from the
//! machine's structure and what the data can show (a backlash needs directions of motion, a
//! thermal lag needs time and the input).

use kin_compiler::basis::{Basis, Wavelength};
use kin_compiler::ir::{Component, FrameRef, JointKind, Machine, Var};
use kin_compiler::units::Dim;

use super::{Candidate, Family};

/// What the measurement files offer for candidates to use.
#[derive(Debug, Clone, Default)]
pub struct Available {
    /// Axes with a direction-of-motion column in every file.
    pub directions: Vec<bool>,
    /// Inputs given in every file.
    pub inputs: Vec<bool>,
    pub time: bool,
    /// How the data sample each axis (`None`: no position of it in the data).
    pub sampled: Vec<Option<Sampling>>,
    /// `reversals[a][b]`: at how many positions of axis `b` the data hold both directions of
    /// motion of axis `a` (its range cut in `REVERSAL_BINS` equal parts, or its distinct
    /// positions when fewer): what a reversal error of `a` that changes along `b` can be seen
    /// at. Empty when not computed.
    pub reversals: Vec<Vec<usize>>,
}

/// The parts an axis' range is cut into to count where another axis reverses.
pub(crate) const REVERSAL_BINS: usize = 8;

/// The positions of one axis the data visit (SI): what a candidate along it can resolve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sampling {
    pub lo: f64,
    pub hi: f64,
    /// The median spacing of the distinct positions: for irregular sampling, the spacing the
    /// Nyquist rule below is stated on (a few close pairs do not resolve short wavelengths).
    pub step: f64,
    pub distinct: usize,
}

impl Sampling {
    /// Positions closer than this (1 nm, 1 nrad) are one position: set points repeated.
    const SAME: f64 = 1e-9;

    /// The sampling of the finite values given; `None` without two distinct positions.
    pub fn of(values: impl Iterator<Item = f64>) -> Option<Sampling> {
        let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        v.dedup_by(|b, a| (*b - *a).abs() <= Self::SAME);
        let (&lo, &hi) = (v.first()?, v.last()?);
        let mut steps: Vec<f64> = v.windows(2).map(|w| w[1] - w[0]).collect();
        steps.sort_by(f64::total_cmp);
        let step = *steps.get(steps.len() / 2)?;
        Some(Sampling {
            lo,
            hi,
            step,
            distinct: v.len(),
        })
    }

    pub fn span(&self) -> f64 {
        self.hi - self.lo
    }

    /// The shortest wavelength the positions resolve: two samples per period (Nyquist).
    pub fn shortest(&self) -> f64 {
        2.0 * self.step
    }

    /// Whether a periodic error of wavelength `lambda` is one the data can tell from others:
    /// no shorter than [`Sampling::shortest`] (it would alias onto a longer one), and repeating
    /// at least [`Sampling::PERIODS`] times over the covered span (fewer periods are a shape,
    /// which more knots describe, not a period the data show).
    pub(crate) fn resolves(&self, lambda: f64) -> bool {
        lambda >= self.shortest() && lambda * Self::PERIODS <= self.span()
    }

    /// The periods a wavelength must repeat over the data to be called periodic.
    pub(crate) const PERIODS: f64 = 3.0;

    /// The harmonics (per revolution) among `orders` whose whole period lies inside the
    /// covered angle: over less than a period a harmonic is a smooth curve the location
    /// constants and each other absorb, and its fit is ill-conditioned (±30° of data cannot
    /// tell 2 per revolution from a tilt and an offset).
    pub fn harmonics(&self, orders: impl Iterator<Item = u32>) -> Vec<u32> {
        orders
            .filter(|&h| h > 0 && self.span() >= std::f64::consts::TAU / h as f64 - Self::SAME)
            .collect()
    }
}

/// A candidate and the text actually compiled to test it: non-linear parameters are tested at
/// a fixed value (chosen by a scan) but suggested as `fit`.
#[derive(Debug, Clone)]
pub struct Proposal {
    pub candidate: Candidate,
    pub test_text: String,
    /// Candidates of one group (e.g. a lag at several time constants) compete: only the best of
    /// a group is reported, but every member counts in the multiple-testing correction.
    pub group: String,
    /// The terms of the line, in order: `candidate.text` is `target += ` and their sum.
    pub terms: Vec<Term>,
    /// For revolute harmonics, the name of the error motion (for restated explanations).
    pub motion: String,
    /// How many independent values of a parameter were searched to place the candidate (the
    /// wavelengths of the spectrum its peak was found in); 1 when none was. The candidate's
    /// F-test is made at the value the search chose, so its p-value is corrected for the search.
    pub searched: f64,
}

/// A spectral peak along a prismatic axis: the wavelength (SI) and how many independent
/// wavelengths its spectrum searched.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    pub axis: usize,
    pub wavelength: f64,
    pub searched: f64,
}

/// One term of a candidate's line. Whether a term adds anything is decided on the data, not
/// here: the library sees the model's text, but a term can repeat what the model has on
/// another frame (`linear(Z)` on `Y.tz` is the `s` of `Z.tz` when both translate alike), and
/// only the design shows it. A line with such a term would make the refit rank-deficient
/// (E0601), so the line given to the user keeps only the terms that add (`restate`).
#[derive(Debug, Clone, PartialEq)]
pub struct Term {
    /// As suggested (`wavelength fit …`).
    pub text: String,
    /// As tested (non-linear parameters fixed at the scanned value).
    pub test: String,
    /// `fourier(V, harmonics h)` as `(V, h)`: one harmonic per term, so that a harmonic the
    /// model has can be left out; adjacent ones on one axis are written as one `fourier`.
    pub harmonic: Option<(String, u32)>,
}

impl Term {
    pub(super) fn new(text: String) -> Term {
        Term {
            test: text.clone(),
            text,
            harmonic: None,
        }
    }

    pub(super) fn harmonic(axis: &str, h: u32) -> Term {
        Term {
            harmonic: Some((axis.to_string(), h)),
            ..Term::new(format!("fourier({axis}, harmonics {h})"))
        }
    }
}

/// `target += ` the terms, as suggested or as tested; runs of harmonics of one axis as one
/// `fourier` (`harmonics 2..4`, `harmonics (2, 4)`, `harmonics 3`).
pub fn line(target: &str, terms: &[&Term], test: bool) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while let Some(t) = terms.get(i) {
        let Some((axis, _)) = &t.harmonic else {
            parts.push(if test { t.test.clone() } else { t.text.clone() });
            i += 1;
            continue;
        };
        let run: Vec<u32> = terms[i..]
            .iter()
            .map_while(|u| match &u.harmonic {
                Some((a, h)) if a == axis => Some(*h),
                _ => None,
            })
            .collect();
        i += run.len().max(1);
        parts.push(format!("fourier({axis}, harmonics {})", harmonics(&run)));
    }
    format!("{target} += {}", parts.join(" + "))
}

/// A harmonics option: `h`, `a..b` when consecutive, else a list.
fn harmonics(hs: &[u32]) -> String {
    match hs {
        [h] => h.to_string(),
        [first, .., last] if hs.windows(2).all(|w| w[1] == w[0] + 1) => {
            format!("{first}..{last}")
        }
        _ => format!(
            "({})",
            hs.iter()
                .map(|h| h.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// What an error motion of a revolute axis is called (ISO 230-7): along or about its own
/// axis it is axial motion or its angular positioning error, across it radial or tilt motion.
pub(super) fn motion_name(comp: Component, axis_direction: [f64; 3]) -> &'static str {
    let own = along(axis_direction);
    match (
        comp.is_rotation(),
        comp == own || comp == rotation_about(axis_direction),
    ) {
        (false, true) => "axial error motion",
        (false, false) => "radial error motion",
        (true, true) => "angular positioning error",
        (true, false) => "tilt error motion",
    }
}

/// `a` or `an` before a motion's name (`an axial error motion`, `a tilt error motion`).
pub(super) fn article(word: &str) -> &'static str {
    if word.starts_with(['a', 'e', 'i', 'o', 'u']) {
        "an"
    } else {
        "a"
    }
}

fn harmonics_explanation(axis: &str, hs: &[u32], motion: &str) -> String {
    let at = match hs {
        [h] => format!("{h}"),
        [first, .., last] if hs.windows(2).all(|w| w[1] == w[0] + 1) => {
            format!("{first} to {last}")
        }
        [init @ .., last] => format!(
            "{} and {last}",
            init.iter()
                .map(|h| h.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        [] => String::new(),
    };
    format!(
        "{} {motion} of the {axis} axis at {at} per revolution (its bearing or drive)",
        article(motion)
    )
}

/// The candidate with only the terms marked `kept` (those that add to the model on the data).
pub(crate) fn restate(p: &Proposal, kept: &[bool]) -> Candidate {
    let terms: Vec<&Term> = p
        .terms
        .iter()
        .zip(kept)
        .filter(|(_, k)| **k)
        .map(|(t, _)| t)
        .collect();
    if terms.len() == p.terms.len() {
        return p.candidate.clone();
    }
    let hs: Vec<u32> = terms
        .iter()
        .filter_map(|t| t.harmonic.as_ref().map(|(_, h)| *h))
        .collect();
    let explanation = match terms.first().and_then(|t| t.harmonic.as_ref()) {
        Some((axis, _)) if p.candidate.family == Family::RevoluteHarmonics => {
            harmonics_explanation(axis, &hs, &p.motion)
        }
        _ => p.candidate.explanation.clone(),
    };
    Candidate {
        text: line(&p.candidate.target, &terms, false),
        explanation,
        ..p.candidate.clone()
    }
}

pub(super) fn frame_name(m: &Machine, f: FrameRef) -> Option<String> {
    let axis = |chain: &[kin_compiler::ir::Element], k: usize| {
        chain
            .get(k)
            .and_then(|e| m.axes.get(e.axis))
            .map(|a| a.name.clone())
    };
    match f {
        FrameRef::Tool(k) => axis(&m.tool_chain, k),
        FrameRef::Workpiece(k) => axis(&m.workpiece_chain, k),
        FrameRef::ToolEnd(None) => Some("tool".into()),
        FrameRef::ToolEnd(Some(i)) => m.tools.get(i).map(|t| t.name.clone()),
        FrameRef::WorkpieceEnd => Some("workpiece".into()),
    }
}

/// The frame of each axis, in chain order.
pub(super) fn axis_frames(m: &Machine) -> Vec<(usize, FrameRef)> {
    let mut out: Vec<(usize, FrameRef)> = m
        .tool_chain
        .iter()
        .enumerate()
        .map(|(k, e)| (e.axis, FrameRef::Tool(k)))
        .collect();
    out.extend(
        m.workpiece_chain
            .iter()
            .enumerate()
            .map(|(k, e)| (e.axis, FrameRef::Workpiece(k))),
    );
    out
}

/// Which of tx, ty, tz lies along a unit direction (the largest component).
pub(super) fn along(direction: [f64; 3]) -> Component {
    let k = (0..3)
        .max_by(|&a, &b| direction[a].abs().total_cmp(&direction[b].abs()))
        .unwrap_or(0);
    [Component::Tx, Component::Ty, Component::Tz][k]
}

pub(super) fn rotation_about(direction: [f64; 3]) -> Component {
    match along(direction) {
        Component::Tx => Component::Rx,
        Component::Ty => Component::Ry,
        _ => Component::Rz,
    }
}

/// Whether a model already has a term of the given shape on a target.
pub(super) fn has(
    m: &Machine,
    frame: FrameRef,
    comp: Component,
    test: impl Fn(&kin_compiler::ir::Term) -> bool,
) -> bool {
    m.errors
        .iter()
        .filter(|e| e.frame == frame && e.component == comp)
        .flat_map(|e| &e.terms)
        .any(test)
}

fn is_const(t: &kin_compiler::ir::Term) -> bool {
    t.coefficients == 1 && t.factors.is_empty()
}

pub(super) fn uses(t: &kin_compiler::ir::Term, v: Var) -> bool {
    t.factors.iter().any(|f| f.var == v)
}

/// Appends a proposal: `target += ` the terms; alone in its group unless `group` is given.
pub(super) fn push(
    out: &mut Vec<Proposal>,
    family: Family,
    target: String,
    terms: Vec<Term>,
    explanation: String,
    group: Option<String>,
) {
    let all: Vec<&Term> = terms.iter().collect();
    let text = line(&target, &all, false);
    let test_text = line(&target, &all, true);
    let group = group.unwrap_or_else(|| test_text.clone());
    out.push(Proposal {
        candidate: Candidate {
            family,
            target,
            also: Vec::new(),
            text,
            explanation,
            no_path: None,
        },
        test_text,
        group,
        terms,
        motion: String::new(),
        searched: 1.0,
    });
}

/// Every candidate the library proposes for `m` given what the data offer. `wavelengths` are
/// spectral peaks found along axes, `taus` the time constants scanned for lags (SI).
pub fn propose(
    m: &Machine,
    available: &Available,
    wavelengths: &[Peak],
    taus: &[f64],
) -> Vec<Proposal> {
    let mut out = Vec::new();
    let length = &m.units.length;
    let angle = &m.units.angle;
    for (a, frame) in axis_frames(m) {
        let Some(axis) = m.axes.get(a) else { continue };
        let Some(name) = frame_name(m, frame) else {
            continue;
        };
        let own = Var::Axis(a);
        let revolute = axis.kind == JointKind::Revolute;
        let motion = along(axis.direction);

        // Missing squareness / axis-location constants.
        // A prismatic carriage's constant offset (its zero along its motion, its location
        // across it) matters where a revolute axis it carries turns the offset; elsewhere it is
        // the chain's one constant translation, which the pass finds already spanned once any
        // other element has it (and says so: `dropped`).
        for comp in Component::ALL {
            if !has(m, frame, comp, is_const) {
                let target = format!("{name}.{}", comp.name());
                let what = if comp.is_rotation() {
                    format!("a constant rotation of the {name} axis about {} (a squareness or tilt of the axes it carries)", &comp.name()[1..])
                } else if revolute {
                    format!("a constant offset of the {name} axis line along {} (an axis-location error)", &comp.name()[1..])
                } else if comp == motion {
                    format!("a constant offset of the {name} carriage along its motion (its zero)")
                } else {
                    format!("a constant offset of the {name} carriage along {} (its location across its motion)", &comp.name()[1..])
                };
                push(
                    &mut out,
                    Family::Constant,
                    target.clone(),
                    vec![Term::new("const".into())],
                    what,
                    None,
                );
            }
        }

        // Angular errors seen through the tool's Abbe offset, with as many knots as the axis'
        // other splines: fewer would leave "more knots" for the next round.
        if !revolute {
            for comp in [Component::Rx, Component::Ry, Component::Rz] {
                if !has(m, frame, comp, |t| uses(t, own)) {
                    let target = format!("{name}.{}", comp.name());
                    push(
&mut out,
                        Family::AbbeAngular,
                        target.clone(),
                        vec![Term::new(format!("spline({}, {})", axis.name, knots_option(m, available, a, sibling_knots(m, frame, own))))],
                        format!("the {} carriage tilts about {} as it travels; the tool sees the tilt times its Abbe offset", axis.name, &comp.name()[1..]),
                        None,
                    );
                }
            }
        }

        // Backlash and hysteresis with the direction of motion.
        if available.directions.get(a).copied().unwrap_or(false) {
            let dir = Var::Direction(a);
            let comps: Vec<Component> = if revolute {
                vec![rotation_about(axis.direction)]
            } else {
                vec![motion, Component::Rx, Component::Ry, Component::Rz]
            };
            for comp in comps {
                if !has(m, frame, comp, |t| uses(t, dir)) {
                    let target = format!("{name}.{}", comp.name());
                    push(
&mut out,
                        Family::Backlash,
                        target.clone(),
                        vec![Term::new(format!("backlash({})", axis.name))],
                        format!("{target} steps with the direction of motion of {}: backlash or hysteresis in its drive or guideways", axis.name),
                        None,
                    );
                }
            }
        }

        // Periodic errors along a prismatic axis, at the spectral peak found for it.
        if !revolute {
            let target = format!("{name}.{}", motion.name());
            super::periodic::propose(&mut out, m, available, wavelengths, a, axis, &target);
        }

        // Error motions of a revolute axis at 2, 3, 4 per revolution, those whose period the
        // data cover (once per revolution: motions.rs, with what the location constants absorb).
        if revolute {
            let hs = available
                .sampled
                .get(a)
                .copied()
                .flatten()
                .map(|s| s.harmonics(2..=4))
                .unwrap_or_default();
            for comp in Component::ALL {
                if !hs.is_empty() && !has(m, frame, comp, |t| uses(t, own)) {
                    let target = format!("{name}.{}", comp.name());
                    let motion = motion_name(comp, axis.direction);
                    push(
                        &mut out,
                        Family::RevoluteHarmonics,
                        target.clone(),
                        hs.iter().map(|&h| Term::harmonic(&axis.name, h)).collect(),
                        harmonics_explanation(&axis.name, &hs, motion),
                        None,
                    );
                    if let Some(last) = out.last_mut() {
                        last.motion = motion.to_string();
                    }
                }
            }
        }

        // Too stiff a model: more knots on a component that already depends on the axis. The
        // text must add only the new knot functions: a second `spline` (or `straightness`)
        // repeats the `s`, `s²` (or the detrended `s²`) the model already has, and a fit of
        // the model with the line added would be rank-deficient (E0601). One period of a
        // periodic spline over the whole range is exactly those knot functions with their
        // `w`, `w²` part removed (eq. 3.12, `w = s`); its knots are placed at least twice as
        // densely as the model's and never on one of them.
        for comp in Component::ALL {
            if has(m, frame, comp, |t| uses(t, own)) && !revolute {
                let target = format!("{name}.{}", comp.name());
                let range = axis.range[1] - axis.range[0];
                let existing: Vec<f64> = m
                    .errors
                    .iter()
                    .filter(|e| e.frame == frame && e.component == comp)
                    .flat_map(|e| &e.terms)
                    .flat_map(|t| &t.factors)
                    .filter(|f| f.var == own)
                    .flat_map(|f| match &f.basis {
                        Basis::Spline { knots, .. } => knots.clone(),
                        Basis::Periodic {
                            knots,
                            wavelength: Wavelength::Fixed(w),
                            ..
                        } if (w - range).abs() <= 1e-9 * range => knots.clone(),
                        _ => Vec::new(),
                    })
                    .collect();
                let clear = |n: usize| {
                    (1..=n).all(|k| {
                        existing
                            .iter()
                            .all(|u| (k as f64 / (n + 1) as f64 - u).abs() > 1e-6)
                    })
                };
                let Some(knots) = (7.max(2 * existing.len() + 1)..=50).find(|&n| clear(n)) else {
                    continue;
                };
                let phase = axis.range[0].rem_euclid(range);
                let exact = |v: f64| {
                    format!(
                        "{} {}",
                        (length.from_si(v) * 1e9).round() / 1e9,
                        length.name
                    )
                };
                let phase = if phase > 1e-9 * range && range - phase > 1e-9 * range {
                    format!(", phase {}", exact(phase))
                } else {
                    String::new()
                };
                push(
&mut out,
                    Family::MoreKnots,
                    target.clone(),
                    vec![Term::new(format!("periodic({}, wavelength {}, knots {knots}{phase})", axis.name, exact(range)))],
                    format!(
                        "{target} varies along {} faster than its model's knots allow: {knots} more knots, evenly spaced (one period over the whole range adds only the new knot functions)",
                        axis.name
                    ),
                    None,
                );
            }
        }

        // Cross-coupling with the other axes and ranged inputs (eq. 3.19: weight of a moving
        // carriage, load).
        for comp in Component::ALL {
            for (b, other) in m.axes.iter().enumerate() {
                // A continuous rotary axis is a periodic variable: an error linear in its angle
                // would jump by the slope × 2π where the angle wraps, which no machine does.
                let periodic = other.kind == JointKind::Revolute && other.continuous;
                if b == a || periodic || has(m, frame, comp, |t| uses(t, Var::Axis(b))) {
                    continue;
                }
                let target = format!("{name}.{}", comp.name());
                let linear = Term::new(format!("linear({})", other.name));
                let (terms, what) = if revolute {
                    (
                        vec![linear],
                        format!("{target} changes with the position of {}", other.name),
                    )
                } else {
                    (
                        vec![linear, Term::new(format!("linear({}) * linear({})", other.name, axis.name))],
                        format!("{target} changes with the position of {} (its weight or moment on {}'s guideways)", other.name, axis.name),
                    )
                };
                push(&mut out, Family::CrossCoupling, target, terms, what, None);
            }
            for (i, input) in m.inputs.iter().enumerate() {
                if !available.inputs.get(i).copied().unwrap_or(false)
                    || input.range.is_none()
                    || input.unit.dim == Dim::TEMPERATURE
                {
                    continue;
                }
                if has(m, frame, comp, |t| uses(t, Var::Input(i))) {
                    continue;
                }
                let target = format!("{name}.{}", comp.name());
                push(
                    &mut out,
                    Family::CrossCoupling,
                    target.clone(),
                    vec![
                        Term::new(format!("linear({})", input.name)),
                        Term::new(format!("linear({}) * linear({})", input.name, axis.name)),
                    ],
                    format!(
                        "{target} changes with {} (a load deflecting the structure)",
                        input.name
                    ),
                    None,
                );
            }
        }
        let _ = angle;
    }

    // The error motions, reversal widths and offsets the families above leave out (the
    // coverage table of spec/diagnosis.md).
    super::motions::propose(m, available, &mut out);

    // Deflection under gravity of what a tilting axis carries (gravity.rs).
    super::gravity::propose(m, available, &mut out);
    super::gravity::propose_arms(m, available, &mut out);

    // Thermal drift: a temperature input through a lag, on the tool (growth of the spindle or
    // ram) and on each prismatic axis' scale.
    for (i, input) in m.inputs.iter().enumerate() {
        if input.unit.dim != Dim::TEMPERATURE || !available.inputs.get(i).copied().unwrap_or(false)
        {
            continue;
        }
        let value = if input.absolute {
            format!("({} - 20 degC)", input.name)
        } else {
            input.name.clone()
        };
        let mut targets: Vec<(String, String)> = [Component::Tx, Component::Ty, Component::Tz]
            .iter()
            .map(|c| (format!("tool.{}", c.name()), "const".to_string()))
            .collect();
        for (a, frame) in axis_frames(m) {
            let (Some(axis), Some(name)) = (m.axes.get(a), frame_name(m, frame)) else {
                continue;
            };
            if axis.kind == JointKind::Prismatic {
                targets.push((
                    format!("{name}.{}", along(axis.direction).name()),
                    format!("linear({})", axis.name),
                ));
            }
        }
        for (target, factor) in targets {
            if available.time && !input.absolute {
                for &tau in taus {
                    let t = format!("{} min", round(tau / 60.0));
                    push(
                        &mut out,
                        Family::Thermal,
                        target.clone(),
                        vec![Term {
                            text: format!("lag({}, tau fit {t}) * {factor}", input.name),
                            test: format!("lag({}, tau {t}) * {factor}", input.name),
                            harmonic: None,
                        }],
                        format!(
                            "{target} follows {} with a thermal lag (time constant ≈ {t})",
                            input.name
                        ),
                        Some(format!("thermal {target} {}", input.name)),
                    );
                }
            }
            push(
                &mut out,
                Family::Thermal,
                target.clone(),
                vec![Term::new(format!("{value} * {factor}"))],
                format!(
                    "{target} follows {} directly (thermal expansion)",
                    input.name
                ),
                Some(format!("thermal {target} {}", input.name)),
            );
        }
    }

    // Heat sources and second time constants (heat.rs).
    super::heat::propose(m, available, taus, &mut out);

    // A slow drift in time of the tool relative to the workpiece.
    if available.time {
        for comp in [Component::Tx, Component::Ty, Component::Tz] {
            let target = format!("tool.{}", comp.name());
            push(
                &mut out,
                Family::Drift,
                target.clone(),
                vec![Term::new("time * const".into())],
                format!(
                    "the tool drifts along {} over time (an unmeasured warm-up)",
                    &comp.name()[1..]
                ),
                None,
            );
        }
        scale_drift(m, &mut out);
        warm_up(m, taus, &mut out);
    }
    out
}

/// Marks every proposal on an axis whose terms use an axis of the other chain: no load or
/// motion path links them. An error of one axis changes with another's position through a
/// load path (the other's weight or moment rides on it, eq. 3.19) or through what one carries
/// of the other; axes on different chains meet only at the machine's base, whose deformation
/// under a moving carriage the model does not express this way. Such a line can still win on
/// BIC where it fits something else by chance: it is kept, ranked after those with a path.
pub fn mark_paths(m: &Machine, proposals: &mut [Proposal]) {
    let chain_of = |name: &str| -> Option<(&'static str, usize)> {
        let tool = m.tool_chain.iter().map(|e| ("tool", e.axis));
        let workpiece = m.workpiece_chain.iter().map(|e| ("workpiece", e.axis));
        tool.chain(workpiece)
            .find(|(_, a)| m.axes.get(*a).is_some_and(|x| x.name == name))
    };
    for p in proposals.iter_mut() {
        let Some((frame, _)) = p.candidate.target.split_once('.') else {
            continue;
        };
        let Some((own, a)) = chain_of(frame) else {
            continue;
        };
        let others: Vec<&str> = p
            .terms
            .iter()
            .flat_map(|t| identifiers(&t.test))
            .filter_map(|word| {
                let (chain, b) = chain_of(word)?;
                (b != a && chain != own).then_some(word)
            })
            .collect();
        if let Some(other) = others.first() {
            p.candidate.no_path = Some(format!(
                "{frame} is on the {own} chain and {other} on the other: no load or motion path links them"
            ));
        }
    }
}

/// The identifiers of a term's text (`linear(X) * backlash(Y)`: linear, X, backlash, Y).
fn identifiers(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| !(c.is_alphanumeric() || c == '_'))
        .filter(|w| {
            w.chars()
                .next()
                .is_some_and(|c| c.is_alphabetic() || c == '_')
        })
}

/// A warm-up that nothing measured follows (thesis §3.4.4, with the step response of the
/// thermal lag of eq. 3.41–3.48): `warmup(time, tau fit τ)`, `1 − e^{−(t − t₀)/τ}` from each
/// run's start, on the tool's translations (`* const`) and on each prismatic axis' scale
/// (`* linear(A)`), at each scanned time constant; the time constants of one target are one
/// group.
fn warm_up(m: &Machine, taus: &[f64], out: &mut Vec<Proposal>) {
    let mut targets: Vec<(FrameRef, Component, String, String, String)> =
        [Component::Tx, Component::Ty, Component::Tz]
            .iter()
            .map(|c| {
                (
                    FrameRef::ToolEnd(None),
                    *c,
                    format!("tool.{}", c.name()),
                    "const".to_string(),
                    format!(
                        "the tool moves along {} as the machine warms up",
                        &c.name()[1..]
                    ),
                )
            })
            .collect();
    for (a, frame) in axis_frames(m) {
        let (Some(axis), Some(name)) = (m.axes.get(a), frame_name(m, frame)) else {
            continue;
        };
        if axis.kind == JointKind::Prismatic {
            let comp = along(axis.direction);
            targets.push((
                frame,
                comp,
                format!("{name}.{}", comp.name()),
                format!("linear({})", axis.name),
                format!("the {} scale grows as the machine warms up", axis.name),
            ));
        }
    }
    for (frame, comp, target, factor, what) in targets {
        if has(m, frame, comp, |t| warms(m, t)) {
            continue;
        }
        for &tau in taus {
            let t = format!("{} min", round(tau / 60.0));
            push(
                out,
                Family::Drift,
                target.clone(),
                vec![Term {
                    text: format!("warmup(time, tau fit {t}) * {factor}"),
                    test: format!("warmup(time, tau {t}) * {factor}"),
                    harmonic: None,
                }],
                format!("{what} (time constant ≈ {t}, no temperature measured)"),
                Some(format!("warmup {target}")),
            );
        }
    }
}

/// Whether a term is scaled by a warm-up.
fn warms(m: &Machine, t: &kin_compiler::ir::Term) -> bool {
    fn walk(m: &Machine, s: &kin_compiler::ir::Scalar) -> bool {
        use kin_compiler::ir::Scalar;
        match s {
            Scalar::Var(Var::Lag(l)) => m.lags.get(*l).is_some_and(|l| l.warmup),
            Scalar::Num(_) | Scalar::Var(_) => false,
            Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => walk(m, a),
            Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
                walk(m, a) || walk(m, b)
            }
        }
    }
    walk(m, &t.scale)
}

/// A prismatic axis' scale that drifts in time (thesis §3.4.4): the positioning error grows in
/// proportion to both the time and the position along the axis, `time * linear(A)`, which a
/// drift of the tool (`time * const`) cannot follow. Where a room or the machine's own warm-up
/// changes a scale's temperature and no temperature is measured, this is what the data show.
fn scale_drift(m: &Machine, out: &mut Vec<Proposal>) {
    for (a, frame) in axis_frames(m) {
        let (Some(axis), Some(name)) = (m.axes.get(a), frame_name(m, frame)) else {
            continue;
        };
        if axis.kind != JointKind::Prismatic {
            continue;
        }
        let comp = along(axis.direction);
        let own = Var::Axis(a);
        if has(m, frame, comp, |t| timed(t) && uses(t, own)) {
            continue;
        }
        let target = format!("{name}.{}", comp.name());
        push(
            out,
            Family::Drift,
            target.clone(),
            vec![Term::new(format!("time * linear({})", axis.name))],
            format!(
                "the {} scale drifts in time: {target} grows along the travel and with the time (a scale warming or cooling without a measured temperature)",
                axis.name
            ),
            None,
        );
    }
}

/// Whether a term is scaled by `time`.
fn timed(t: &kin_compiler::ir::Term) -> bool {
    fn has_time(s: &kin_compiler::ir::Scalar) -> bool {
        use kin_compiler::ir::Scalar;
        match s {
            Scalar::Var(Var::Time) => true,
            Scalar::Num(_) | Scalar::Var(_) => false,
            Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => has_time(a),
            Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
                has_time(a) || has_time(b)
            }
        }
    }
    has_time(&t.scale)
}

/// The knot count a new spline along axis `own` on `frame` takes: the most any spline of that
/// frame along it has (its siblings), at least 2.
pub(super) fn sibling_knots(m: &Machine, frame: FrameRef, own: Var) -> usize {
    m.errors
        .iter()
        .filter(|e| e.frame == frame)
        .flat_map(|e| &e.terms)
        .flat_map(|t| &t.factors)
        .filter(|f| f.var == own)
        .filter_map(|f| match &f.basis {
            Basis::Spline { knots, .. } => Some(knots.len()),
            _ => None,
        })
        .fold(2, usize::max)
}

/// The `knots` option of a new spline with `n` knots along axis `a`: `knots n`, evenly over
/// the declared range, when the data reach both ends of it within half a knot spacing; else `n`
/// knots evenly over the range the data cover, written as positions (`knots at (…) UNIT`). A
/// knot the data do not reach gives a function that is zero (or a multiple of another) on
/// every row: the line would add a column the data cannot see and be dropped as not
/// identifiable — a joint declared over ±360° and measured over ±90° would never get a spline.
pub(super) fn knots_option(m: &Machine, available: &Available, a: usize, n: usize) -> String {
    let (Some(axis), Some(Some(s))) = (m.axes.get(a), available.sampled.get(a)) else {
        return format!("knots {n}");
    };
    let [lo, hi] = axis.range;
    let spacing = (hi - lo) / (n + 1) as f64;
    if n == 0 || (s.lo <= lo + spacing / 2.0 && s.hi >= hi - spacing / 2.0) || s.span() <= 0.0 {
        return format!("knots {n}");
    }
    let unit = if axis.kind == JointKind::Revolute {
        &m.units.angle
    } else {
        &m.units.length
    };
    let at: Vec<String> = (1..=n)
        .map(|k| {
            let x = s.lo + s.span() * k as f64 / (n + 1) as f64;
            round_at(
                unit.from_si(x),
                unit.from_si(s.lo + s.span()) - unit.from_si(s.lo),
            )
            .to_string()
        })
        .collect();
    format!("knots at ({}) {}", at.join(", "), unit.name)
}

/// `v` rounded to four significant digits of `span` (knot positions need no more).
fn round_at(v: f64, span: f64) -> f64 {
    let p = 10f64.powi(3 - span.abs().max(1e-300).log10().floor() as i32);
    (v * p).round() / p
}

pub(super) fn round(v: f64) -> f64 {
    let p = 10f64.powi(4 - v.abs().log10().ceil().max(0.0) as i32);
    (v * p).round() / p
}

#[cfg(test)]
mod tests {
    use super::*;

    fn proposal(family: Family, target: &str, terms: Vec<Term>, explanation: String) -> Proposal {
        let all: Vec<&Term> = terms.iter().collect();
        Proposal {
            candidate: Candidate {
                family,
                target: target.into(),
                also: Vec::new(),
                text: line(target, &all, false),
                explanation,
                no_path: None,
            },
            test_text: line(target, &all, true),
            group: String::new(),
            terms,
            motion: "radial error motion".into(),
            searched: 1.0,
        }
    }

    /// A joint declared over ±360° and measured over ±90°: the spline's knots go where the
    /// data are, and the line compiles; data over the whole range keep `knots N`.
    /// A mill: Y and X move the table (workpiece chain), Z the spindle (tool chain). X's
    /// weight rides on Y, so Y's error may change with X; nothing links Z to the table's axes.
    #[test]
    fn couplings_across_chains_have_no_physical_path() {
        let src = "machine mill {
            task position
            units { length mm, error um, tilt urad }
            axis Y prismatic along -y range 0 mm .. 400 mm
            axis X prismatic along -x range 0 mm .. 500 mm
            axis Z prismatic along z range -300 mm .. 0 mm
            workpiece chain {
                Y fixed
                X fixed at (0, 0, 100) mm
                workpiece at (0, 0, 0) mm
            }
            tool chain {
                Z moving at (0, 0, 500) mm
                tool spindle at (0, 0, -100) mm
            }
            errors {
                X.tx = linear(X)
            }
        }";
        let Some(c) = kin_compiler::compile(src).compiled else {
            panic!("{src}")
        };
        let term = |t: &str| vec![Term::new(t.into())];
        let mut all = vec![
            proposal(
                Family::CrossCoupling,
                "Y.tz",
                term("linear(X)"),
                String::new(),
            ),
            proposal(
                Family::CrossCoupling,
                "Z.tx",
                term("linear(X)"),
                String::new(),
            ),
            proposal(
                Family::Backlash,
                "Y.ty",
                term("linear(Z) * backlash(Y)"),
                String::new(),
            ),
            proposal(
                Family::Drift,
                "tool.tx",
                term("time * const"),
                String::new(),
            ),
        ];
        mark_paths(&c.machine, &mut all);
        let marked: Vec<bool> = all.iter().map(|p| p.candidate.no_path.is_some()).collect();
        assert_eq!(marked, [false, true, true, false]);
        assert_eq!(
            all[1].candidate.no_path.as_deref(),
            Some("Z is on the tool chain and X on the other: no load or motion path links them")
        );
    }

    #[test]
    fn motions_take_their_article() {
        assert!(harmonics_explanation("C", &[2], "axial error motion").starts_with("an axial"));
        assert!(
            harmonics_explanation("C", &[2, 3], "angular positioning error")
                .starts_with("an angular")
        );
        assert!(harmonics_explanation("C", &[2], "tilt error motion").starts_with("a tilt"));
    }

    #[test]
    fn knots_are_placed_over_the_range_the_data_cover() {
        let src = "machine arm {\n    task position\n    units { length mm, angle deg, error um, tilt urad }\n    axis J1 revolute about z range -360 deg .. 360 deg\n    tool chain {\n        J1 fixed\n        tool flange at (500, 0, 0) mm\n    }\n    errors {\n        J1.rz = const\n    }\n}\n";
        let Some(c) = kin_compiler::compile(src).compiled else {
            panic!("{src}")
        };
        let deg = std::f64::consts::PI / 180.0;
        let at = |lo: f64, hi: f64| Available {
            sampled: vec![Sampling::of(
                (0..=36).map(|k| (lo + (hi - lo) * f64::from(k) / 36.0) * deg),
            )],
            ..Available::default()
        };
        let text = |a: &Available| {
            propose(&c.machine, a, &[], &[])
                .into_iter()
                .find(|p| p.candidate.family == Family::ErrorMotion)
                .map(|p| p.candidate.text)
        };
        let part = text(&at(-90.0, 90.0));
        assert_eq!(
            part.as_deref(),
            Some("J1.rz += spline(J1, knots at (-30, 30) deg)")
        );
        let with = src.replace(
            "J1.rz = const",
            &format!("J1.rz = const\n        {}", part.unwrap_or_default()),
        );
        assert!(kin_compiler::compile(&with).compiled.is_some(), "{with}");
        assert_eq!(
            text(&at(-355.0, 355.0)).as_deref(),
            Some("J1.rz += spline(J1, knots 2)")
        );
    }

    #[test]
    fn harmonics_are_written_as_one_fourier() {
        let terms: Vec<Term> = (2..=4).map(|h| Term::harmonic("C", h)).collect();
        let p = proposal(
            Family::RevoluteHarmonics,
            "C.tx",
            terms,
            harmonics_explanation("C", &[2, 3, 4], "radial error motion"),
        );
        assert_eq!(p.candidate.text, "C.tx += fourier(C, harmonics 2..4)");
        assert_eq!(restate(&p, &[true, true, true]), p.candidate);
        let gap = restate(&p, &[true, false, true]);
        assert_eq!(gap.text, "C.tx += fourier(C, harmonics (2, 4))");
        assert!(gap
            .explanation
            .contains("radial error motion of the C axis at 2 and 4 per revolution"));
        assert_eq!(
            restate(&p, &[false, true, true]).text,
            "C.tx += fourier(C, harmonics 3..4)"
        );
        let one = restate(&p, &[false, false, true]);
        assert_eq!(one.text, "C.tx += fourier(C, harmonics 4)");
        assert!(one.explanation.contains("at 4 per revolution"));
    }

    #[test]
    fn a_coupling_keeps_the_terms_that_add() {
        let p = proposal(
            Family::CrossCoupling,
            "Y.tz",
            vec![
                Term::new("linear(X)".into()),
                Term::new("linear(X) * linear(Y)".into()),
            ],
            "Y.tz changes with the position of X".into(),
        );
        assert_eq!(
            p.candidate.text,
            "Y.tz += linear(X) + linear(X) * linear(Y)"
        );
        let product = restate(&p, &[false, true]);
        assert_eq!(product.text, "Y.tz += linear(X) * linear(Y)");
        assert_eq!(product.explanation, p.candidate.explanation);
        assert_eq!(restate(&p, &[true, false]).text, "Y.tz += linear(X)");
    }

    #[test]
    fn fitted_parameters_are_suggested_as_fit_and_tested_fixed() {
        let p = proposal(
            Family::Thermal,
            "tool.tz",
            vec![Term {
                text: "lag(T, tau fit 30 min) * const".into(),
                test: "lag(T, tau 30 min) * const".into(),
                harmonic: None,
            }],
            String::new(),
        );
        assert_eq!(
            p.candidate.text,
            "tool.tz += lag(T, tau fit 30 min) * const"
        );
        assert_eq!(p.test_text, "tool.tz += lag(T, tau 30 min) * const");
    }
}
