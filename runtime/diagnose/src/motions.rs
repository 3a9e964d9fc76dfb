//! The error motions of an axis along its own travel and the reversal errors whose width
//! varies with position: the rows of the coverage table (`coverage.rs`, spec/diagnosis.md) that the older
//! families of [`super::library`] do not generate. Each candidate is proposed only when the
//! model lacks it and the data can show it (directions of motion, a covered revolution).

use kin_compiler::basis::Basis;
use kin_compiler::ir::{Component, FrameRef, JointKind, Machine, Var};

use super::library::{
    along, article, axis_frames, frame_name, has, knots_option, line, motion_name, push,
    rotation_about, sibling_knots, uses, Available, Proposal, Term,
};
use super::Family;

/// Appends the candidates of the rows this module generates.
pub(super) fn propose(m: &Machine, available: &Available, out: &mut Vec<Proposal>) {
    for (a, frame) in axis_frames(m) {
        let (Some(axis), Some(name)) = (m.axes.get(a), frame_name(m, frame)) else {
            continue;
        };
        let own = Var::Axis(a);
        let knots = sibling_knots(m, frame, own);
        // The option as written: over the data's range where they do not reach the ends.
        let knots_at = knots_option(m, available, a, knots);
        if axis.kind == JointKind::Prismatic {
            travel(
                m,
                frame,
                &name,
                &axis.name,
                own,
                along(axis.direction),
                &knots_at,
                out,
            );
        } else {
            let sampled = available.sampled.get(a).copied().flatten();
            let full = sampled.as_ref().is_some_and(covers_revolution);
            let (axial, angular) = (along(axis.direction), rotation_about(axis.direction));
            if full {
                let siblings = sampled.map(|s| s.harmonics(2..=4)).unwrap_or_default();
                for comp in [axial, angular] {
                    once_per_rev(m, frame, &name, &axis.name, comp, &siblings, out);
                }
                // Radial and tilt motion at once per revolution: what no location constant
                // absorbs (see `once_per_rev`).
                for comp in Component::ALL {
                    if comp != axial && comp != angular {
                        once_per_rev(m, frame, &name, &axis.name, comp, &siblings, out);
                    }
                }
            } else if !axis.continuous
                && sampled.is_some()
                && !has(m, frame, angular, |t| uses(t, own))
            {
                // Over less than a turn the angular positioning error is a curve along the
                // range, as for a prismatic axis; harmonics would be ill-conditioned there. A
                // continuous axis is left out: its angles wrap, and a spline over the turn
                // would join the two ends of the data seen across 0°.
                let target = format!("{name}.{}", angular.name());
                push(
                    out,
                    Family::ErrorMotion,
                    target.clone(),
                    vec![Term::new(format!("spline({}, {knots_at})", axis.name))],
                    format!(
                        "{target} varies over the range of {}: an angular positioning error of the axis (its encoder or drive)",
                        axis.name
                    ),
                    None,
                );
            }
        }
        if available.directions.get(a).copied().unwrap_or(false) {
            let comps: Vec<Component> = if axis.kind == JointKind::Revolute {
                vec![rotation_about(axis.direction)]
            } else {
                vec![
                    along(axis.direction),
                    Component::Rx,
                    Component::Ry,
                    Component::Rz,
                ]
            };
            for &comp in &comps {
                // A continuous axis wraps: a reversal width linear in its angle would jump by
                // the slope × 2π where the angle wraps.
                if !(axis.kind == JointKind::Revolute && axis.continuous) {
                    reversal_width(m, frame, &name, &axis.name, a, comp, &knots_at, out);
                }
                for (b, other) in m.axes.iter().enumerate() {
                    let at = available
                        .reversals
                        .get(a)
                        .and_then(|r| r.get(b))
                        .copied()
                        .unwrap_or(0);
                    // The same wrap for the other axis' angle.
                    let periodic = other.kind == JointKind::Revolute && other.continuous;
                    if b == a || periodic || at < ACROSS_LINEAR {
                        continue;
                    }
                    let across = Across {
                        a,
                        b,
                        axis: &axis.name,
                        other: &other.name,
                        knots: sibling_knots(m, frame, Var::Axis(b)),
                        knots_at: knots_option(
                            m,
                            available,
                            b,
                            sibling_knots(m, frame, Var::Axis(b)),
                        ),
                        positions: at,
                    };
                    reversal_across(m, frame, &name, comp, &across, out);
                }
            }
        }
    }
}

/// Positions of the other axis with reversals of the axis, at least, for a reversal width
/// linear along the other axis: two fix a line, a third tests it.
pub(super) const ACROSS_LINEAR: usize = 3;

/// A reversal of axis `a` seen as an error that depends on the position of axis `b`.
struct Across<'a> {
    a: usize,
    b: usize,
    axis: &'a str,
    other: &'a str,
    /// Knots of a spline along `b` on this frame (its siblings', at least 2).
    knots: usize,
    /// The same as the `knots` option written (over the data's range of `b` where needed).
    knots_at: String,
    /// Positions of `b` with reversals of `a` in the data.
    positions: usize,
}

/// A reversal error of one axis whose width changes with the position of another (Soons 1993,
/// §3.2.5 with §3.3.2): the clearance of a carriage's guideway or the windup of its drive
/// changes as another carriage moves its weight or its moment arm, so the step at a reversal of
/// A grows along B (`linear(B) * backlash(A)`, `spline(B, knots N) * backlash(A)`). Nested
/// with A's constant step exactly as [`reversal_width`] is, and in the same group: one
/// reversal finding per component, in whichever form pays for its columns. Proposed only when
/// the data reverse A at several positions of B (a spline needs a position per function and
/// one more).
fn reversal_across(
    m: &Machine,
    frame: FrameRef,
    name: &str,
    comp: Component,
    x: &Across,
    out: &mut Vec<Proposal>,
) {
    let (dir, along_b) = (Var::Direction(x.a), Var::Axis(x.b));
    let target = format!("{name}.{}", comp.name());
    let step_only = |t: &kin_compiler::ir::Term| t.factors.len() == 1 && uses(t, dir);
    if has(m, frame, comp, |t| uses(t, dir) && uses(t, along_b)) {
        return;
    }
    let constant = has(m, frame, comp, step_only);
    if !constant && has(m, frame, comp, |t| uses(t, dir)) {
        return;
    }
    let step = Term::new(format!("backlash({})", x.axis));
    let kind = if comp.is_rotation() {
        "angular hysteresis"
    } else {
        "backlash"
    };
    let group = if constant {
        format!("reversal width {target}")
    } else {
        line(&target, &[&step], true)
    };
    let mut forms = vec![format!("linear({}) * backlash({})", x.other, x.axis)];
    // spline(B, knots N) has N + 2 functions.
    if x.positions > x.knots + 2 {
        forms.push(format!(
            "spline({}, {}) * backlash({})",
            x.other, x.knots_at, x.axis
        ));
    }
    for width in forms {
        let mut terms = Vec::new();
        if !constant {
            terms.push(step.clone());
        }
        terms.push(Term::new(width));
        push(
            out,
            Family::Backlash,
            target.clone(),
            terms,
            format!(
                "{target} steps with the direction of motion of {} by an amount that changes with the position of {}: {kind} whose width depends on where {} is (its weight or moment on {}'s guideways or drive)",
                x.axis, x.other, x.other, x.axis
            ),
            Some(group.clone()),
        );
    }
}

/// A prismatic axis' positioning error along its travel (eq. 3.1) and straightness across it
/// (eq. 3.4–3.8), for components with no term in the axis' position yet. The positioning
/// error is offered as a scale error (`linear`) and as a spline; both are one group, so the
/// one with the better information criterion is reported.
#[allow(clippy::too_many_arguments)]
fn travel(
    m: &Machine,
    frame: FrameRef,
    name: &str,
    axis: &str,
    own: Var,
    motion: Component,
    knots: &str,
    out: &mut Vec<Proposal>,
) {
    for comp in [Component::Tx, Component::Ty, Component::Tz] {
        if has(m, frame, comp, |t| uses(t, own)) {
            // A scale error alone along the motion (`linear(A)`) leaves the shape of the
            // positioning error out: offered as the curve with its line removed, which adds
            // exactly what the line lacks (a spline would repeat the line's column, and the
            // candidate would be dropped for it).
            if comp == motion && !has(m, frame, comp, |t| uses(t, own) && !is_line_of(t, own)) {
                let target = format!("{name}.{}", comp.name());
                push(
                    out,
                    Family::ErrorMotion,
                    target.clone(),
                    vec![Term::new(format!("straightness({axis}, {knots})"))],
                    format!("{target} varies along {axis} beyond the scale error the model has: the shape of the axis' positioning error (its scale or leadscrew)"),
                    None,
                );
            }
            continue;
        }
        let target = format!("{name}.{}", comp.name());
        if comp == motion {
            let group = format!("positioning {target}");
            push(
                out,
                Family::ErrorMotion,
                target.clone(),
                vec![Term::new(format!("linear({axis})"))],
                format!("{target} grows in proportion to the travel of {axis}: a scale error of its measuring system"),
                Some(group.clone()),
            );
            push(
                out,
                Family::ErrorMotion,
                target.clone(),
                vec![Term::new(format!("spline({axis}, {knots})"))],
                format!("{target} varies along {axis}: a positioning error of the axis (its scale or leadscrew)"),
                Some(group),
            );
        } else {
            push(
                out,
                Family::ErrorMotion,
                target.clone(),
                vec![Term::new(format!("straightness({axis}, {knots})"))],
                format!("the {axis} carriage does not travel straight along {}: a straightness error of its guideway (the linear trend is a squareness)", &comp.name()[1..]),
                None,
            );
        }
    }
}

/// Whether `t` is `linear(v)` alone (a scale error, no shape).
fn is_line_of(t: &kin_compiler::ir::Term, v: Var) -> bool {
    matches!(
        t.factors.as_slice(),
        [f] if f.var == v && matches!(f.basis, kin_compiler::basis::Basis::Linear { .. })
    )
}

/// Once-per-revolution error motion of a revolute axis that covers a revolution, on one
/// component. Axial motion and the angular positioning error at once per revolution are not
/// absorbed by any constant. Across the axis (radial and tilt motion) the first harmonic of
/// the two components, written in the axis' non-rotating frame, is the sum of a vector that
/// turns with the axis and one that turns the other way (spec/diagnosis.md derives it): a
/// constant of what the axis carries (the workpiece's location on the table) is the first;
/// the second is an error motion no constant absorbs. One component's first harmonic spans,
/// with those constants, the whole counter-rotating part; what the model's constants already
/// span is left out by the identifiability test of the diagnosis, which drops the candidate
/// when nothing is new. Offered alone and with the 2 … 4 per revolution the library tests
/// anyway, in that candidate's group, so the reading with the better information criterion
/// is the finding.
fn once_per_rev(
    m: &Machine,
    frame: FrameRef,
    name: &str,
    axis: &str,
    comp: Component,
    siblings: &[u32],
    out: &mut Vec<Proposal>,
) {
    let Some(a) = m.axes.iter().position(|x| x.name == axis) else {
        return;
    };
    let own = Var::Axis(a);
    // A term in the angle that can follow a sinusoid of one period already holds it.
    let holds_first = |t: &kin_compiler::ir::Term| {
        t.factors.iter().any(|f| {
            f.var == own
                && match &f.basis {
                    Basis::Fourier { harmonics, .. } => harmonics.contains(&1),
                    Basis::Spline { detrend, .. } => {
                        *detrend != kin_compiler::basis::Detrend::OncePerRev
                    }
                    Basis::Sign => false,
                    _ => true,
                }
        })
    };
    if has(m, frame, comp, holds_first) {
        return;
    }
    let target = format!("{name}.{}", comp.name());
    let motion = m
        .axes
        .get(a)
        .map(|x| motion_name(comp, x.direction))
        .unwrap_or("error motion");
    let others = !siblings.is_empty() && !has(m, frame, comp, |t| uses(t, own));
    // Across the axis the first harmonic is a group of its own: in the 2 … 4 line's group it
    // would take that line's place in the list whenever neither is significant.
    let across = matches!(motion, "radial error motion" | "tilt error motion");
    let group = if others && !across {
        let terms: Vec<Term> = siblings.iter().map(|&h| Term::harmonic(axis, h)).collect();
        let all: Vec<&Term> = terms.iter().collect();
        line(&target, &all, true)
    } else {
        format!("once per revolution {target}")
    };
    let first = out.len();
    let what = match motion {
        "radial error motion" | "tilt error motion" => format!(
            "{} {motion} of the {axis} axis at once per revolution that does not turn with it (it turns the other way or keeps its direction: bearing races of unequal waviness, a drive pulling to one side); the part turning with the axis is the location of what it carries",
            article(motion)
        ),
        _ => format!(
            "{} {motion} of the {axis} axis at once per revolution (a tilted or eccentric bearing face, an eccentric encoder), which no location error absorbs",
            article(motion)
        ),
    };
    push(
        out,
        Family::RevoluteHarmonics,
        target.clone(),
        vec![Term::harmonic(axis, 1)],
        what.clone(),
        Some(group.clone()),
    );
    if others {
        let mut terms = vec![Term::harmonic(axis, 1)];
        terms.extend(siblings.iter().map(|&h| Term::harmonic(axis, h)));
        push(
            out,
            Family::RevoluteHarmonics,
            target,
            terms,
            what,
            Some(group),
        );
    }
    for p in out.iter_mut().skip(first) {
        p.motion = motion.to_string();
    }
}

/// Whether the positions of a revolute axis go round: the arc the visited angles leave
/// uncovered is no wider than two sampling steps or 10° (random angles leave a few steps at
/// the wrap; 0°, 90°, 180°, 270° leave one step), at three positions at least (a sinusoid of
/// one period has a cosine, a sine and the mean to fit).
fn covers_revolution(s: &super::library::Sampling) -> bool {
    let turn = std::f64::consts::TAU;
    s.distinct >= 3
        && s.span() <= turn * (1.0 + 1e-9)
        && turn - s.span() <= (2.0 * s.step).max(turn / 36.0)
}

/// A reversal error whose width varies with the axis' position (Soons 1993, §3.2.5: the
/// clearance varies along the guideway; a leadscrew's elastic windup grows with the length in
/// the loop). Nested with the constant step: with the constant in the model, the extension
/// alone; without it, the constant plus the extension, in the constant's group, so that the
/// extended form is the finding only when its information criterion beats the constant's.
#[allow(clippy::too_many_arguments)]
fn reversal_width(
    m: &Machine,
    frame: FrameRef,
    name: &str,
    axis: &str,
    a: usize,
    comp: Component,
    knots: &str,
    out: &mut Vec<Proposal>,
) {
    let (own, dir) = (Var::Axis(a), Var::Direction(a));
    let target = format!("{name}.{}", comp.name());
    let step_only = |t: &kin_compiler::ir::Term| t.factors.len() == 1 && uses(t, dir);
    let with_position = |t: &kin_compiler::ir::Term| uses(t, dir) && uses(t, own);
    if has(m, frame, comp, with_position) {
        return;
    }
    let constant = has(m, frame, comp, step_only);
    if !constant && has(m, frame, comp, |t| uses(t, dir)) {
        // Some other reversal term the model states (e.g. across axes): leave it to the user.
        return;
    }
    let step = Term::new(format!("backlash({axis})"));
    let kind = if comp.is_rotation() {
        "angular hysteresis"
    } else {
        "backlash"
    };
    let group = if constant {
        format!("reversal width {target}")
    } else {
        line(&target, &[&step], true)
    };
    for width in [
        format!("linear({axis}) * backlash({axis})"),
        format!("spline({axis}, {knots}) * backlash({axis})"),
    ] {
        let mut terms = Vec::new();
        if !constant {
            terms.push(step.clone());
        }
        terms.push(Term::new(width));
        push(
            out,
            Family::Backlash,
            target.clone(),
            terms,
            format!("{target} steps with the direction of motion of {axis} by an amount that changes along {axis}: {kind} whose width varies with position (clearance along the guideway, windup of the drive)"),
            Some(group.clone()),
        );
    }
}
