//! What the candidate library covers, as a table: for each kind of element and error
//! component, the families of Soons' chapter 3 that apply, the rule that admits a candidate,
//! and the section it comes from. spec/diagnosis.md states the same table for users; the tests
//! below generate every row on machines that lack it, and classify every candidate the library
//! proposes into a row, so that neither side can lose a row unnoticed.

use kin_compiler::ir::{JointKind, Machine};

use super::library::{along, rotation_about, Proposal};
use super::Family;

/// The kind of element a candidate is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Element {
    Prismatic,
    Revolute,
    /// The tool end (`tool`, or one tool by name).
    Tool,
}

/// The components of a row, relative to the element's axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Components {
    /// The translation along the axis (a prismatic axis' motion, a revolute axis' axial motion).
    Along,
    /// The translations across the axis.
    Across,
    /// The rotation about the axis.
    About,
    /// The rotations about the other two directions.
    Tilt,
    /// All three rotations.
    Rotations,
    /// All six components.
    All,
    /// tx, ty, tz.
    Translations,
    /// The translations across the axis and the rotations about the directions across it: how
    /// a beam along the axis bends.
    Bending,
}

/// One row of the coverage table.
#[derive(Debug, Clone, Copy)]
pub(super) struct Row {
    /// A short stable key, also the row's name in spec/diagnosis.md.
    pub key: &'static str,
    pub element: Element,
    pub components: Components,
    pub family: Family,
    /// The form of the line, as proposed.
    pub form: &'static str,
}

/// The table. The rule that admits each row and its thesis section are in spec/diagnosis.md,
/// next to the same key.
pub(super) const ROWS: &[Row] = &[
    Row {
        key: "squareness",
        element: Element::Prismatic,
        components: Components::Rotations,
        family: Family::Constant,
        form: "const",
    },
    Row {
        key: "offset",
        element: Element::Prismatic,
        components: Components::Translations,
        family: Family::Constant,
        form: "const",
    },
    Row {
        key: "angular-motion",
        element: Element::Prismatic,
        components: Components::Rotations,
        family: Family::AbbeAngular,
        form: "spline(A, knots N)",
    },
    Row {
        key: "positioning",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::ErrorMotion,
        form: "linear(A) | spline(A, knots N)",
    },
    Row {
        key: "positioning-shape",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::ErrorMotion,
        form: "straightness(A, knots N)",
    },
    Row {
        key: "straightness",
        element: Element::Prismatic,
        components: Components::Across,
        family: Family::ErrorMotion,
        form: "straightness(A, knots N)",
    },
    Row {
        key: "more-knots",
        element: Element::Prismatic,
        components: Components::All,
        family: Family::MoreKnots,
        form: "periodic(A, wavelength range, knots M)",
    },
    Row {
        key: "periodic",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::Periodic,
        form: "periodic(A, wavelength fit λ, …)",
    },
    Row {
        key: "backlash",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::Backlash,
        form: "backlash(A)",
    },
    Row {
        key: "backlash-width",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::Backlash,
        form: "[backlash(A) +] linear(A) * backlash(A) | spline(A, knots N) * backlash(A)",
    },
    Row {
        key: "hysteresis",
        element: Element::Prismatic,
        components: Components::Rotations,
        family: Family::Backlash,
        form: "backlash(A)",
    },
    Row {
        key: "hysteresis-width",
        element: Element::Prismatic,
        components: Components::Rotations,
        family: Family::Backlash,
        form: "[backlash(A) +] linear(A) * backlash(A) | spline(A, knots N) * backlash(A)",
    },
    Row {
        key: "backlash-across",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::Backlash,
        form: "[backlash(A) +] linear(B) * backlash(A) | spline(B, knots N) * backlash(A)",
    },
    Row {
        key: "hysteresis-across",
        element: Element::Prismatic,
        components: Components::Rotations,
        family: Family::Backlash,
        form: "[backlash(A) +] linear(B) * backlash(A) | spline(B, knots N) * backlash(A)",
    },
    Row {
        key: "coupling-axis",
        element: Element::Prismatic,
        components: Components::All,
        family: Family::CrossCoupling,
        form: "linear(B) + linear(B) * linear(A)",
    },
    Row {
        key: "coupling-input",
        element: Element::Prismatic,
        components: Components::All,
        family: Family::CrossCoupling,
        form: "linear(I) + linear(I) * linear(A)",
    },
    Row {
        key: "thermal-scale",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::Thermal,
        form: "T * linear(A) | lag(T, tau fit τ) * linear(A)",
    },
    Row {
        key: "beam-bending",
        element: Element::Prismatic,
        components: Components::Bending,
        family: Family::Thermal,
        form: "beam(A, ends at (…), upper at (T, T), lower at (T', T'), gap d, across g) * const",
    },
    Row {
        key: "location",
        element: Element::Revolute,
        components: Components::All,
        family: Family::Constant,
        form: "const",
    },
    Row {
        key: "harmonics",
        element: Element::Revolute,
        components: Components::All,
        family: Family::RevoluteHarmonics,
        form: "fourier(A, harmonics 2..4)",
    },
    Row {
        key: "once-per-rev",
        element: Element::Revolute,
        components: Components::Along,
        family: Family::RevoluteHarmonics,
        form: "fourier(A, harmonics 1) | fourier(A, harmonics 1..4)",
    },
    Row {
        key: "once-per-rev-angular",
        element: Element::Revolute,
        components: Components::About,
        family: Family::RevoluteHarmonics,
        form: "fourier(A, harmonics 1) | fourier(A, harmonics 1..4)",
    },
    Row {
        key: "once-per-rev-radial",
        element: Element::Revolute,
        components: Components::Across,
        family: Family::RevoluteHarmonics,
        form: "fourier(A, harmonics 1) | fourier(A, harmonics 1..4)",
    },
    Row {
        key: "once-per-rev-tilt",
        element: Element::Revolute,
        components: Components::Tilt,
        family: Family::RevoluteHarmonics,
        form: "fourier(A, harmonics 1) | fourier(A, harmonics 1..4)",
    },
    Row {
        key: "angular-positioning",
        element: Element::Revolute,
        components: Components::About,
        family: Family::ErrorMotion,
        form: "spline(A, knots N)",
    },
    Row {
        key: "rotary-backlash",
        element: Element::Revolute,
        components: Components::About,
        family: Family::Backlash,
        form: "backlash(A)",
    },
    Row {
        key: "rotary-backlash-width",
        element: Element::Revolute,
        components: Components::About,
        family: Family::Backlash,
        form: "[backlash(A) +] linear(A) * backlash(A) | spline(A, knots N) * backlash(A)",
    },
    Row {
        key: "rotary-backlash-across",
        element: Element::Revolute,
        components: Components::About,
        family: Family::Backlash,
        form: "[backlash(A) +] linear(B) * backlash(A) | spline(B, knots N) * backlash(A)",
    },
    Row {
        key: "rotary-coupling-axis",
        element: Element::Revolute,
        components: Components::All,
        family: Family::CrossCoupling,
        form: "linear(B)",
    },
    Row {
        key: "gravity",
        element: Element::Revolute,
        components: Components::All,
        family: Family::CrossCoupling,
        form: "sin(B) * const + cos(B) * const",
    },
    Row {
        key: "arm-compliance",
        element: Element::Revolute,
        components: Components::About,
        family: Family::CrossCoupling,
        form: "cos(Φ_k) * const + sin(Φ_k) * const for each link k of the joint's parallel group",
    },
    Row {
        key: "arm-payload",
        element: Element::Revolute,
        components: Components::About,
        family: Family::CrossCoupling,
        form: "each arm-compliance column scaled by a payload's weight (a force input)",
    },
    Row {
        key: "gravity-carriage",
        element: Element::Prismatic,
        components: Components::All,
        family: Family::CrossCoupling,
        form: "sin(B) * const + cos(B) * const",
    },
    Row {
        key: "gravity-end",
        element: Element::Tool,
        components: Components::All,
        family: Family::CrossCoupling,
        form: "sin(B) * const + cos(B) * const",
    },
    Row {
        key: "rotary-coupling-input",
        element: Element::Revolute,
        components: Components::All,
        family: Family::CrossCoupling,
        form: "linear(I) + linear(I) * linear(A)",
    },
    Row {
        key: "thermal-tool",
        element: Element::Tool,
        components: Components::Translations,
        family: Family::Thermal,
        form: "T * const | lag(T, tau fit τ) * const",
    },
    Row {
        key: "drift",
        element: Element::Tool,
        components: Components::Translations,
        family: Family::Drift,
        form: "time * const",
    },
    Row {
        key: "drift-scale",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::Drift,
        form: "time * linear(A)",
    },
    Row {
        key: "warm-up",
        element: Element::Tool,
        components: Components::Translations,
        family: Family::Drift,
        form: "warmup(time, tau fit τ) * const",
    },
    Row {
        key: "warm-up-scale",
        element: Element::Prismatic,
        components: Components::Along,
        family: Family::Drift,
        form: "warmup(time, tau fit τ) * linear(A)",
    },
];

/// The row a proposal of the library belongs to; `None` if no row describes it (the table is
/// then incomplete, which the tests below catch).
pub(super) fn classify(m: &Machine, p: &Proposal) -> Option<&'static Row> {
    let (frame, comp) = p.candidate.target.split_once('.')?;
    let axis = m.axes.iter().enumerate().find(|(_, a)| a.name == frame);
    let element = match axis {
        Some((_, a)) if a.kind == JointKind::Prismatic => Element::Prismatic,
        Some(_) => Element::Revolute,
        None => Element::Tool,
    };
    let (relation, rotation) = match axis {
        Some((_, a)) => {
            let (on, about) = (
                along(a.direction).name(),
                rotation_about(a.direction).name(),
            );
            let rot = comp.starts_with('r');
            let rel = match (rot, comp == on || comp == about) {
                (false, true) => Components::Along,
                (false, false) => Components::Across,
                (true, true) => Components::About,
                (true, false) => Components::Tilt,
            };
            (rel, rot)
        }
        None => (Components::Translations, comp.starts_with('r')),
    };
    let fits = |c: Components| match c {
        Components::All => true,
        Components::Rotations => rotation,
        Components::Translations => !rotation,
        Components::Bending => matches!(relation, Components::Across | Components::Tilt),
        c => c == relation,
    };
    let text = &p.test_text;
    let width = text.contains(" * backlash(");
    // A width along another axis: a `linear(B)` or `spline(B, …)` factor of the step.
    let across = width
        && axis.is_some_and(|(_, a)| {
            m.axes.iter().any(|b| {
                b.name != a.name
                    && (text.contains(&format!("linear({}) * backlash(", b.name))
                        || text.contains(&format!("spline({}, ", b.name)))
            })
        });
    let first = text.contains("harmonics 1)") || text.contains("harmonics 1..");
    let beam = text.contains("beam(");
    let warm = text.contains("warmup(");
    // A joint's compliance under its links' gravity torque: cos/sin pairs, cos first (the
    // tilting-axis rows write sin first).
    let arm = text
        .split_once(" += ")
        .is_some_and(|(_, terms)| terms.starts_with("cos("));
    // The same columns scaled by a payload's weight: `payload / 1 N * cos(…) * const …`.
    let payload = text.split_once(" += ").is_some_and(|(_, terms)| {
        m.inputs
            .iter()
            .any(|i| terms.starts_with(&format!("{} / 1 ", i.name)) && terms.contains("* cos("))
    });
    let arm = arm || payload;
    let gravity = text.contains("sin(") && !arm;
    let input = axis.is_some_and(|(_, a)| {
        m.inputs
            .iter()
            .any(|i| text.contains(&format!("linear({}) * linear({})", i.name, a.name)))
    }) || (axis.is_some_and(|(_, a)| a.kind == JointKind::Revolute)
        && m.inputs
            .iter()
            .any(|i| text.contains(&format!("linear({})", i.name))));
    ROWS.iter().find(|r| {
        r.element == element
            && r.family == p.candidate.family
            && fits(r.components)
            && match r.key {
                "backlash" | "hysteresis" | "rotary-backlash" => !width,
                "backlash-width" | "hysteresis-width" | "rotary-backlash-width" => width && !across,
                "backlash-across" | "hysteresis-across" | "rotary-backlash-across" => across,
                "positioning" => !text.contains("straightness("),
                "positioning-shape" => text.contains("straightness("),
                "harmonics" => !first,
                "once-per-rev"
                | "once-per-rev-angular"
                | "once-per-rev-radial"
                | "once-per-rev-tilt" => first,
                "coupling-axis" | "rotary-coupling-axis" => !input && !gravity && !arm,
                "coupling-input" | "rotary-coupling-input" => input && !gravity && !arm,
                "gravity" | "gravity-carriage" | "gravity-end" => gravity,
                "arm-compliance" => arm && !payload,
                "arm-payload" => payload,
                "thermal-scale" => !beam,
                "drift" | "drift-scale" => !warm,
                "warm-up" | "warm-up-scale" => warm,
                "beam-bending" => beam,
                _ => true,
            }
    })
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use kin_compiler::compile;

    use super::super::library::{propose, Available, Sampling};
    use super::*;

    /// A machine with every kind of element and nearly no error model: every row that needs
    /// nothing in the model is lacking. `extra` is added to the errors block.
    fn machine(extra: &str) -> Machine {
        let src = format!(
            r#"
machine cover {{
    task position
    units {{ length mm, angle deg, error um, tilt urad, time min, force N }}
    axis X prismatic along x range 0 mm .. 800 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis C revolute about z continuous
    axis A revolute about x range -30 deg .. 30 deg
    input T : temperature rise
    input T_low : temperature rise
    input load : force range 0 N .. 500 N
    workpiece chain {{
        Y moving
        C moving at (0, 0, 50) mm
        workpiece at (0, 0, 0) mm
    }}
    tool chain {{
        X moving
        A moving at (0, 0, 400) mm
        tool probe at (0, 0, -100) mm
    }}
    errors {{
        Y.ty = linear(Y)
{extra}
    }}
}}
"#
        );
        let out = compile(&src);
        match out.compiled {
            Some(c) => c.machine,
            None => panic!("{src}\n{:#?}", out.diagnostics),
        }
    }

    /// Everything in the data: directions of every axis, both inputs, time, each axis sampled
    /// over its range (the C axis every 10°).
    fn available(m: &Machine) -> Available {
        let sampled = m
            .axes
            .iter()
            .map(|a| {
                let hi = if a.continuous {
                    a.range[1] - a.range[1] / 36.0
                } else {
                    a.range[1]
                };
                Sampling::of((0..=35).map(|k| a.range[0] + (hi - a.range[0]) * k as f64 / 35.0))
            })
            .collect();
        Available {
            directions: vec![true; m.axes.len()],
            inputs: vec![true; m.inputs.len()],
            time: true,
            sampled,
            // Every axis reverses in every part of every other's range.
            reversals: vec![vec![super::super::library::REVERSAL_BINS; m.axes.len()]; m.axes.len()],
        }
    }

    fn rows(m: &Machine) -> BTreeSet<&'static str> {
        let a = available(m);
        // A spectral peak along X of 100 mm, which 36 positions over 800 mm resolve.
        let mut proposals = propose(
            m,
            &a,
            &[super::super::library::Peak {
                axis: 0,
                wavelength: 0.1,
                searched: 1.0,
            }],
            &[600.0],
        );
        super::super::beam::propose(m, &a, &Default::default(), &mut proposals);
        let mut keys = BTreeSet::new();
        for p in &proposals {
            match classify(m, p) {
                Some(r) => {
                    keys.insert(r.key);
                }
                None => panic!("no row of the table describes `{}`", p.candidate.text),
            }
        }
        keys
    }

    #[test]
    fn every_row_is_generated_on_a_machine_that_lacks_it() {
        let mut keys = rows(&machine(""));
        // Rows that extend what the model has: more knots on a spline, a reversal width on a
        // constant step.
        keys.extend(rows(&machine(
            "        X.tx = spline(X, knots 2) + backlash(X)\n        X.rz = backlash(X)",
        )));
        // A scale error alone: the shape of the positioning error on top of it.
        keys.extend(rows(&machine("        X.tx = linear(X)")));
        // A tilting axis carrying a carriage: gravity on a prismatic element.
        let src = "machine tilt {\n    task position\n    units { length mm, angle deg, error um, tilt urad }\n    axis A revolute about x range -30 deg .. 30 deg\n    axis X prismatic along x range 0 mm .. 100 mm\n    workpiece chain {\n        A fixed\n        X moving\n        workpiece at (0, 0, 0) mm\n    }\n    tool chain {\n        tool probe at (0, 0, 100) mm\n    }\n}\n";
        match compile(src).compiled {
            Some(c) => keys.extend(rows(&c.machine)),
            None => panic!("{src}"),
        }
        // A shoulder and an elbow, parallel and horizontal, on a vertical base joint, carrying
        // a payload whose weight the data give.
        let arm = "machine arm {\n    task position\n    units { length mm, angle deg, error um, tilt urad, force N }\n    input payload : force range 0 N .. 100 N\n    axis J1 revolute about z range -180 deg .. 180 deg\n    axis J2 revolute about y range -90 deg .. 90 deg\n    axis J3 revolute about y range -90 deg .. 90 deg\n    tool chain {\n        J1 moving\n        J2 moving at (0, 0, 400) mm\n        J3 moving at (500, 0, 0) mm\n        tool t at (400, 0, 0) mm\n    }\n}\n";
        match compile(arm).compiled {
            Some(c) => keys.extend(rows(&c.machine)),
            None => panic!("{arm}"),
        }
        let all: BTreeSet<&str> = ROWS.iter().map(|r| r.key).collect();
        let missing: Vec<&&str> = all.difference(&keys).collect();
        assert!(missing.is_empty(), "rows never generated: {missing:?}");
    }

    #[test]
    fn keys_are_unique_and_stated_in_the_spec() {
        let spec = include_str!("../../../spec/diagnosis.md");
        let mut seen = BTreeSet::new();
        for r in ROWS {
            assert!(seen.insert(r.key), "key {} twice", r.key);
            assert!(!r.form.is_empty(), "row {} states no form", r.key);
            assert!(
                spec.contains(&format!("| `{}` |", r.key)),
                "spec/diagnosis.md has no row `{}`",
                r.key
            );
        }
    }

    #[test]
    fn new_splines_take_the_knots_of_their_siblings() {
        let m = machine("        X.ty = straightness(X, knots 5)");
        let proposals = propose(&m, &available(&m), &[], &[]);
        let abbe = proposals
            .iter()
            .find(|p| p.candidate.target == "X.ry" && p.candidate.family == Family::AbbeAngular);
        assert_eq!(
            abbe.map(|p| p.candidate.text.as_str()),
            Some("X.ry += spline(X, knots 5)")
        );
        let straight = proposals
            .iter()
            .find(|p| p.candidate.target == "X.tz" && p.candidate.family == Family::ErrorMotion);
        assert_eq!(
            straight.map(|p| p.candidate.text.as_str()),
            Some("X.tz += straightness(X, knots 5)")
        );
    }

    /// A reversal width along another axis needs reversals at several of its positions: none
    /// without them, the linear form from three, the spline from a position per function and
    /// one more.
    #[test]
    fn a_reversal_across_axes_needs_reversals_along_the_other_axis() {
        let m = machine("");
        let across = |at: usize| -> Vec<String> {
            let mut a = available(&m);
            a.reversals = vec![vec![at; m.axes.len()]; m.axes.len()];
            propose(&m, &a, &[], &[])
                .into_iter()
                .filter(|p| p.candidate.target == "X.tx")
                .map(|p| p.candidate.text)
                .filter(|t| t.contains("(Y) * backlash(X)") || t.contains("spline(Y, knots"))
                .collect()
        };
        assert!(across(0).is_empty() && across(2).is_empty());
        assert_eq!(
            across(3),
            vec!["X.tx += backlash(X) + linear(Y) * backlash(X)"]
        );
        let all = across(8);
        assert_eq!(all.len(), 2, "{all:?}");
        assert!(all.contains(&"X.tx += backlash(X) + spline(Y, knots 2) * backlash(X)".to_string()));
        // Never along a continuous rotary axis (its angle wraps).
        let mut a = available(&m);
        a.reversals = vec![vec![8; m.axes.len()]; m.axes.len()];
        assert!(propose(&m, &a, &[], &[]).iter().all(|p| !p
            .candidate
            .text
            .contains("(C) * backlash(")
            && !p.candidate.text.contains("spline(C, ")));
    }

    #[test]
    fn a_limited_rotary_axis_gets_no_once_per_revolution_term() {
        let m = machine("");
        let proposals = propose(&m, &available(&m), &[], &[]);
        assert!(proposals
            .iter()
            .filter(|p| p.candidate.target.starts_with("A."))
            .all(|p| !p.test_text.contains("fourier")));
        assert!(proposals
            .iter()
            .any(|p| p.candidate.text == "A.rx += spline(A, knots 2)"));
        assert!(proposals
            .iter()
            .any(|p| p.candidate.text == "C.rz += fourier(C, harmonics 1)"));
    }
}
