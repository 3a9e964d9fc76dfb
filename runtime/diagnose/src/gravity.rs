//! Deflection under gravity of what a tilting rotary axis carries (spec/diagnosis.md,
//! "Gravity on a tilting axis"). A frame that turns with a revolute axis A and with no other
//! joint's rotation sees gravity as `R(u, q)ᵀ g`: the part of g along A's direction u stays,
//! the part across it turns with the angle, so every component of that vector is
//! `a + b cos q + c sin q`. A linearly compliant structure (a table on its bearing, a fixture,
//! a head on its trunnion) deflects in proportion to the load it sees in its own frame, so each
//! of its six parametric errors is `a + b cos q + c sin q`: the constant is a location, the two
//! others the candidate `sin(A) * const + cos(A) * const`. Where A is vertical, g lies along u
//! and nothing turns. Gravity is the model's (`gravity along …`, −z of the base by default).

use kin_compiler::ir::{Component, FrameKind, FrameRef, JointKind, Machine, Var};

use super::library::{frame_name, has, push, uses, Available, Proposal, Term};
use super::Family;

/// An axis whose direction is within this (the sine of the angle) of gravity's is vertical:
/// the turning part of gravity is at most this fraction of it, far below any deflection a
/// measurement resolves against the constant part.
const VERTICAL: f64 = 1e-3;

/// Appends, for each revolute axis that is not vertical and that the data move, the sin/cos
/// couplings on every component of each frame it carries that lacks a term in its angle.
pub(super) fn propose(m: &Machine, available: &Available, out: &mut Vec<Proposal>) {
    let chains = [(&m.tool_chain, true), (&m.workpiece_chain, false)];
    for (chain, tool) in chains {
        for (j, e) in chain.iter().enumerate() {
            let Some(axis) = m.axes.get(e.axis) else {
                continue;
            };
            if axis.kind != JointKind::Revolute
                || !available.sampled.get(e.axis).is_some_and(|s| s.is_some())
                || m.home_direction(e.axis)
                    .is_none_or(|u| across(u, m.gravity) <= VERTICAL)
            {
                continue;
            }
            for frame in carried(m, chain, j, tool) {
                let Some(name) = frame_name(m, frame) else {
                    continue;
                };
                for comp in Component::ALL {
                    if has(m, frame, comp, |t| uses(t, Var::Axis(e.axis))) {
                        continue;
                    }
                    let target = format!("{name}.{}", comp.name());
                    push(
                        out,
                        Family::CrossCoupling,
                        target.clone(),
                        vec![
                            Term::new(format!("sin({}) * const", axis.name)),
                            Term::new(format!("cos({}) * const", axis.name)),
                        ],
                        format!(
                            "{target} deflects under the weight {} carries: tilting {} turns gravity in the frame of what it carries, so a compliant structure deflects as a·sin {} + b·cos {}",
                            axis.name, axis.name, axis.name, axis.name
                        ),
                        None,
                    );
                }
            }
        }
    }
}

/// Appends, for each revolute joint of a serial arm whose axis is not vertical, its deflection
/// under the gravity torque of the links it carries (joint compliance; spec/diagnosis.md,
/// "Joint compliance of an arm"). Joints parallel to it, before and after, form a planar group:
/// a point mass on link k of the group (anywhere on it) has its lever about the joint's axis
/// turn with `Φ_k`, the sum of the group's angles up to k (signed by each axis' sense), so the
/// torque — and a linear compliance's deflection — is `Σ_k a_k cos Φ_k + b_k sin Φ_k`: known
/// columns of the angles, linear in the unknown mass moments. Joints before the group must be
/// vertical (turning about gravity changes no lever); the group ends at the first joint that is
/// not parallel (the masses beyond it are counted with the last link of the group: their
/// lever also turns with that joint, which the form leaves out) or at a prismatic one.
pub(super) fn propose_arms(m: &Machine, available: &Available, out: &mut Vec<Proposal>) {
    let g = m.gravity;
    for (chain, tool) in [(&m.tool_chain, true), (&m.workpiece_chain, false)] {
        let dir =
            |k: usize| -> Option<[f64; 3]> { chain.get(k).and_then(|e| m.home_direction(e.axis)) };
        let revolute = |k: usize| {
            chain
                .get(k)
                .and_then(|e| m.axes.get(e.axis))
                .is_some_and(|a| a.kind == JointKind::Revolute)
        };
        let sense = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        for (j, e) in chain.iter().enumerate() {
            let (Some(axis), Some(u)) = (m.axes.get(e.axis), dir(j)) else {
                continue;
            };
            if axis.kind != JointKind::Revolute
                || across(u, g) <= VERTICAL
                || !available.sampled.get(e.axis).is_some_and(|s| s.is_some())
            {
                continue;
            }
            // The joints before: vertical ones turn nothing; parallel ones join the sum.
            let mut before: Vec<(f64, &str)> = Vec::new();
            let mut planar = true;
            for k in 0..j {
                let (Some(a), Some(d)) = (chain.get(k).and_then(|x| m.axes.get(x.axis)), dir(k))
                else {
                    continue;
                };
                if a.kind != JointKind::Revolute || across(d, g) <= VERTICAL {
                    continue;
                }
                if across(d, u) <= VERTICAL {
                    before.push((sense(d, u).signum(), a.name.as_str()));
                } else {
                    planar = false;
                }
            }
            if !planar {
                continue;
            }
            // The group after j, up to the first joint that breaks the plane.
            let mut sums: Vec<String> = Vec::new();
            let mut angle: Vec<(f64, &str)> = before.clone();
            angle.push((1.0, axis.name.as_str()));
            sums.push(signed_sum(&angle));
            for k in j + 1..chain.len() {
                let (Some(a), Some(d)) = (chain.get(k).and_then(|x| m.axes.get(x.axis)), dir(k))
                else {
                    break;
                };
                if !revolute(k) || across(d, u) > VERTICAL {
                    break;
                }
                angle.push((sense(d, u).signum(), a.name.as_str()));
                sums.push(signed_sum(&angle));
            }
            // A joint alone in its group, with nothing before it, tilts only what it carries:
            // on its own moving frame that is the tilting-axis line `propose` gives already.
            if sums.len() == 1 && before.is_empty() && e.frame == FrameKind::Moving {
                continue;
            }
            let Some(name) = super::library::frame_name(m, at(tool, j)) else {
                continue;
            };
            let comp = super::library::rotation_about(axis.direction);
            let target = format!("{name}.{}", comp.name());
            let terms = |scale: &str| -> Vec<Term> {
                sums.iter()
                    .flat_map(|phi| {
                        [
                            Term::new(format!("{scale}cos({phi}) * const")),
                            Term::new(format!("{scale}sin({phi}) * const")),
                        ]
                    })
                    .collect()
            };
            let links = sums.len();
            push(
                out,
                Family::CrossCoupling,
                target.clone(),
                terms(""),
                format!(
                    "{target}: {} deflects under the gravity torque of the {} it carries (joint compliance): each link's weight has its lever turn with the sum of the parallel joints' angles up to it",
                    axis.name,
                    if links == 1 { "link".to_string() } else { format!("{links} links") }
                ),
                None,
            );
            // A payload whose weight the data give (a force input): its torque about the joint
            // is that weight times a lever from the same angle sums (the payload sits beyond
            // the group's last link), so the same columns scaled by it — the deflection that
            // changes with what the robot carries.
            for (i, input) in m.inputs.iter().enumerate() {
                if input.unit.dim != kin_compiler::units::Dim::FORCE
                    || !available.inputs.get(i).copied().unwrap_or(false)
                {
                    continue;
                }
                let scale = format!("{} / 1 {} * ", input.name, input.unit.name);
                push(
                    out,
                    Family::CrossCoupling,
                    target.clone(),
                    terms(&scale),
                    format!(
                        "{target}: {} deflects under the torque of the payload `{}` (joint compliance): its weight times a lever that turns with the sum of the parallel joints' angles",
                        axis.name, input.name
                    ),
                    None,
                );
            }
        }
    }
}

/// `J2 + J3 - J4`: a sum of signed joint angles, as the language writes it.
fn signed_sum(angles: &[(f64, &str)]) -> String {
    let mut s = String::new();
    for (i, (sign, name)) in angles.iter().enumerate() {
        match (i, *sign < 0.0) {
            (0, false) => s.push_str(name),
            (0, true) => {
                s.push('-');
                s.push_str(name);
            }
            (_, false) => s.push_str(&format!(" + {name}")),
            (_, true) => s.push_str(&format!(" - {name}")),
        }
    }
    s
}

/// The frame of element `k` of the tool chain (`tool`) or the workpiece chain.
fn at(tool: bool, k: usize) -> FrameRef {
    if tool {
        FrameRef::Tool(k)
    } else {
        FrameRef::Workpiece(k)
    }
}

/// The frames that turn with the joint of element `j` and with no other rotation: its own when
/// it is `moving` (placed after its joint), the later elements' up to and including the first
/// later revolute one that is `fixed` (placed before its own joint), and the chain's end when no
/// later revolute joint lies between (spec/kinematics.md: a moving frame sits after its joint,
/// a fixed one before it).
fn carried(
    m: &Machine,
    chain: &[kin_compiler::ir::Element],
    j: usize,
    tool: bool,
) -> Vec<FrameRef> {
    let at = |k: usize| {
        if tool {
            FrameRef::Tool(k)
        } else {
            FrameRef::Workpiece(k)
        }
    };
    let mut out = Vec::new();
    if chain.get(j).is_some_and(|e| e.frame == FrameKind::Moving) {
        out.push(at(j));
    }
    for (k, e) in chain.iter().enumerate().skip(j + 1) {
        let revolute = m
            .axes
            .get(e.axis)
            .is_some_and(|a| a.kind == JointKind::Revolute);
        if !revolute {
            out.push(at(k));
            continue;
        }
        // A later revolute joint: its fixed frame still turns only with j's; beyond it,
        // gravity also turns with its angle.
        if e.frame == FrameKind::Fixed {
            out.push(at(k));
        }
        return out;
    }
    out.push(if tool {
        FrameRef::ToolEnd(None)
    } else {
        FrameRef::WorkpieceEnd
    });
    out
}

/// `|a × b|` of two unit vectors: the sine of the angle between them.
fn across(a: [f64; 3], b: [f64; 3]) -> f64 {
    let c = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
}

#[cfg(test)]
mod tests {
    use kin_compiler::compile;

    use super::super::library::Sampling;
    use super::*;

    fn machine(b_about: &str) -> Machine {
        on_wall(b_about, "")
    }

    /// A shoulder–elbow arm carrying a payload whose weight the data give: the compliance of
    /// each parallel joint is proposed alone and scaled by the payload.
    #[test]
    fn an_arm_with_a_payload_gets_its_compliance_scaled_by_the_weight() {
        let src = "machine arm {
            task position
            units { length mm, angle deg, error um, tilt urad, force N }
            axis J1 revolute about z range -170 deg .. 170 deg
            axis J2 revolute about z range -90 deg .. 90 deg
            axis J3 revolute about z range -120 deg .. 120 deg
            input payload : force range 0 N .. 100 N
            tool chain { J1 moving
                         J2 moving at (0, 0, 400) mm rot (90, 0, 0) deg
                         J3 moving at (600, 0, 0) mm
                         tool t at (500, 0, 0) mm }
            errors { J2.rz = const  J3.rz = const  J1.tx = payload / 100 N * const }
        }";
        let m = match compile(src).compiled {
            Some(c) => c.machine,
            None => panic!("{src}"),
        };
        let sampled = m
            .axes
            .iter()
            .map(|a| {
                Sampling::of([a.range[0], 0.5 * (a.range[0] + a.range[1]), a.range[1]].into_iter())
            })
            .collect();
        let mut with = Available {
            sampled,
            inputs: vec![true],
            ..Available::default()
        };
        let mut out = Vec::new();
        propose_arms(&m, &with, &mut out);
        let t: Vec<String> = out.iter().map(|p| p.candidate.text.clone()).collect();
        assert!(
            t.contains(&"J2.rz += payload / 1 N * cos(J2) * const + payload / 1 N * sin(J2) * const + payload / 1 N * cos(J2 + J3) * const + payload / 1 N * sin(J2 + J3) * const".to_string()),
            "{t:?}"
        );
        assert!(
            t.contains(&"J2.rz += cos(J2) * const + sin(J2) * const + cos(J2 + J3) * const + sin(J2 + J3) * const".to_string()),
            "{t:?}"
        );
        // Data without the payload's column: no scaled line.
        with.inputs = vec![false];
        let mut out = Vec::new();
        propose_arms(&m, &with, &mut out);
        assert!(out.iter().all(|p| !p.candidate.text.contains("payload")));
    }

    /// The trunnion with a `gravity` declaration (`""`: none, gravity −z).
    fn on_wall(b_about: &str, gravity: &str) -> Machine {
        let src = format!(
            r#"
machine trunnion {{
    task position
    {gravity}
    units {{ length mm, angle deg, error um, tilt urad }}
    axis X prismatic along x range 0 mm .. 500 mm
    axis B revolute about {b_about} range -90 deg .. 90 deg
    axis C revolute about z continuous
    workpiece chain {{
        X fixed
        B fixed at (0, 0, 100) mm
        C fixed at (0, 0, 50) mm
        workpiece at (0, 0, 0) mm
    }}
    tool chain {{
        tool probe at (0, 0, 300) mm
    }}
    errors {{
        C.tx = const + linear(B)
    }}
}}
"#
        );
        match compile(&src).compiled {
            Some(c) => c.machine,
            None => panic!("{src}"),
        }
    }

    fn targets(m: &Machine) -> Vec<String> {
        let available = Available {
            sampled: m
                .axes
                .iter()
                .map(|a| {
                    Sampling::of(
                        [a.range[0], 0.5 * (a.range[0] + a.range[1]), a.range[1]].into_iter(),
                    )
                })
                .collect(),
            ..Available::default()
        };
        let mut out = Vec::new();
        propose(m, &available, &mut out);
        out.iter().map(|p| p.candidate.text.clone()).collect()
    }

    /// A B axis about y carries the C table's fixed frame, which turns with B only; the
    /// workpiece also turns with C, so its gravity depends on both angles and it is left out.
    /// A component with a term in B already (`linear(B)`) gets none.
    #[test]
    fn a_tilting_table_carries_the_rotary_tables_frame() {
        let t = targets(&machine("y"));
        assert!(
            t.contains(&"C.tz += sin(B) * const + cos(B) * const".to_string()),
            "{t:?}"
        );
        assert!(
            t.contains(&"C.rx += sin(B) * const + cos(B) * const".to_string()),
            "{t:?}"
        );
        assert_eq!(t.len(), 5, "{t:?}");
        assert!(t
            .iter()
            .all(|x| x.starts_with("C.") && !x.starts_with("C.tx")));
    }

    /// A vertical axis turns nothing of gravity: no candidate.
    #[test]
    fn a_vertical_axis_gets_none() {
        assert!(targets(&machine("z")).iter().all(|t| !t.contains("(B)")));
    }

    /// Vertical is the model's gravity, not the base's z: on a machine mounted with gravity
    /// along −x, an axis about z tilts what it carries and one about x does not.
    #[test]
    fn vertical_follows_the_declared_gravity() {
        let m = on_wall("z", "gravity along -x");
        assert_eq!(m.gravity, [-1.0, 0.0, 0.0]);
        assert!(
            targets(&m).iter().any(|t| t.contains("sin(B)")),
            "{:?}",
            targets(&m)
        );
        let m = on_wall("x", "gravity along (-2, 0, 0)");
        assert_eq!(m.gravity, [-1.0, 0.0, 0.0]);
        assert!(targets(&m).iter().all(|t| !t.contains("(B)")));
    }
}
