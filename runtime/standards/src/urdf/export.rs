//! URDF export: a machine with its fitted constant errors folded into the joints' origins
//! (`kin export urdf`, spec/urdf.md "Export").
//!
//! The exact kinematics (spec/kinematics.md, eq. 2.35–2.38 with eq. 2.8) is a product, from the
//! base out, of fixed transforms — shapes `S_k` and error transforms `E_k` — and joint motions
//! `J_k(q)`: a moving element contributes `S_k · J_k · E_k`, a fixed one `S_k · E_k` with its
//! `J_k` carried to the front of the next step. Where every error is constant, the fixed
//! transforms between two joint motions multiply to one rigid transform, and that is a URDF
//! joint's `<origin>`: its motion about `<axis>` follows, as kin's joint motion follows the
//! same product. So the calibrated machine is a URDF whose forward kinematics equal kin's exact
//! model of the constant errors, to rounding. Terms that vary with the pose (a spline, a
//! gravity term, a backlash) have no place in a URDF and are listed as left out.

use kin_compiler::ir::{FrameKind, FrameRef, JointKind, Machine, Scalar, Shape};
use kin_model::exact::shape_or_error;
use kin_model::interp::{Interpreter, State};
use kin_model::kinematics::FrameErrors;
use nalgebra::{Matrix4, Rotation3};
use thiserror::Error;

/// A URDF written from a machine.
#[derive(Debug, Clone)]
pub struct Exported {
    pub text: String,
    /// Moving joints written.
    pub joints: usize,
    /// Coefficients whose values were folded into origins.
    pub folded: usize,
    /// Terms that vary with the pose and so were left out, named by their first coefficient
    /// (`J2.rz[1] (cos(J2))`) or their component for a fixed term.
    pub left_out: Vec<String>,
}

#[derive(Debug, Error)]
pub enum ExportError {
    #[error("the model cannot be evaluated: {0}")]
    Eval(String),
    #[error("a folded origin is not finite (a coefficient far too large): {0}")]
    NotFinite(String),
}

/// A term's scale as text (`cos(J2)`, `payload / 100`), or `None` when it is 1.
fn scale_text(m: &Machine, s: &Scalar) -> Option<String> {
    fn text(m: &Machine, s: &Scalar) -> String {
        let both =
            |a: &Scalar, op: &str, b: &Scalar| format!("({} {op} {})", text(m, a), text(m, b));
        match s {
            Scalar::Num(v) => format!("{v}"),
            Scalar::Var(v) => kin_model::interp::var_name(*v, m),
            Scalar::Neg(a) => format!("-{}", text(m, a)),
            Scalar::Sin(a) => format!("sin({})", text(m, a)),
            Scalar::Cos(a) => format!("cos({})", text(m, a)),
            Scalar::Add(a, b) => both(a, "+", b),
            Scalar::Sub(a, b) => both(a, "-", b),
            Scalar::Mul(a, b) => both(a, "*", b),
            Scalar::Div(a, b) => both(a, "/", b),
        }
    }
    match s {
        Scalar::Num(v) if *v == 1.0 => None,
        _ => Some(text(m, s)),
    }
}

fn frame_name(m: &Machine, frame: FrameRef) -> String {
    let axis = |chain: &[kin_compiler::ir::Element], k: usize| {
        chain
            .get(k)
            .and_then(|e| m.axes.get(e.axis))
            .map_or_else(|| "?".to_string(), |a| a.name.clone())
    };
    match frame {
        FrameRef::Tool(k) => axis(&m.tool_chain, k),
        FrameRef::Workpiece(k) => axis(&m.workpiece_chain, k),
        FrameRef::ToolEnd(None) => "tool".into(),
        FrameRef::ToolEnd(Some(t)) => m.tools.get(t).map_or("tool".into(), |t| t.name.clone()),
        FrameRef::WorkpieceEnd => "workpiece".into(),
    }
}

/// One moving joint of a calibrated chain: the rigid transform from the previous joint's frame
/// (after its motion) to this joint's frame, and the motion about or along `axis` there.
#[derive(Debug, Clone)]
pub struct CalibratedJoint {
    pub name: String,
    pub kind: JointKind,
    pub continuous: bool,
    /// The joint's range, SI (meaningless for a continuous joint).
    pub range: [f64; 2],
    /// From the frame after the previous joint's motion (the base for the first).
    pub origin: Matrix4<f64>,
    /// The direction of the motion in the joint's frame, unit length.
    pub axis: [f64; 3],
}

/// A machine's chains with every constant error folded into rigid transforms: what a URDF or a
/// DH table of the calibrated machine is written from.
#[derive(Debug, Clone)]
pub struct Calibrated {
    pub tool_chain: Vec<CalibratedJoint>,
    /// Each tool: its name and the transform from the frame after the tool chain's last motion.
    pub tools: Vec<(String, Matrix4<f64>)>,
    pub workpiece_chain: Vec<CalibratedJoint>,
    /// From the frame after the workpiece chain's last motion to the workpiece.
    pub workpiece: Matrix4<f64>,
    /// Coefficients whose values were folded.
    pub folded: usize,
    /// Terms that vary with the pose, left out (as [`Exported::left_out`]).
    pub left_out: Vec<String>,
}

/// The machine `m` (its bound β) with its constant errors folded into its chains' transforms.
pub fn calibrated(m: &Machine) -> Result<Calibrated, ExportError> {
    let mut constant_part = m.clone();
    let mut left_out = Vec::new();
    let mut folded = 0;
    for model in &mut constant_part.errors {
        let mut kept = Vec::new();
        for term in std::mem::take(&mut model.terms) {
            if term.is_constant() {
                folded += term.coefficients;
                kept.push(term);
            } else {
                let scaled = match scale_text(m, &term.scale) {
                    Some(s) => format!("{s} · "),
                    None => String::new(),
                };
                left_out.push(match m.coefficients.get(term.first) {
                    Some(c) if term.coefficients > 0 => {
                        format!("{} ({scaled}{})", c.name, c.label)
                    }
                    _ => format!(
                        "a fixed term of {}.{}",
                        frame_name(m, model.frame),
                        model.component.name()
                    ),
                });
            }
        }
        model.terms = kept;
    }
    let beta = if m.beta.len() == m.coefficients.len() {
        m.beta.clone()
    } else {
        vec![0.0; m.coefficients.len()]
    };
    let mut it = Interpreter::new(&constant_part).map_err(|e| ExportError::Eval(e.to_string()))?;
    // Constant errors do not depend on the state: any pose and inputs will do.
    let q = vec![0.0; m.axes.len()];
    let inputs = vec![0.0; m.inputs.len()];
    let lags = vec![0.0; m.lags.len()];
    let dirs = vec![1.0; m.axes.len()];
    let errors_of = |it: &mut Interpreter<'_>, tool: usize| -> Result<FrameErrors, ExportError> {
        let mut e = FrameErrors::zeros(&constant_part);
        let state = State {
            q: &q,
            inputs: &inputs,
            lags: &lags,
            time: 0.0,
            dirs: &dirs,
            tool,
            tool_offset: None,
        };
        it.frame_errors(&state, &beta, &mut e)
            .map_err(|e| ExportError::Eval(e.to_string()))?;
        Ok(e)
    };
    let errors = errors_of(&mut it, 0)?;
    let (tool_chain, after_tool) = chain(m, &m.tool_chain, &errors.tool_chain);
    let mut tools = Vec::with_capacity(m.tools.len());
    for (t, tool) in m.tools.iter().enumerate() {
        let e = errors_of(&mut it, t)?;
        tools.push((
            tool.name.clone(),
            after_tool * shape(&tool.offset) * error(&e.tool_end),
        ));
    }
    let (workpiece_chain, after_workpiece) = chain(m, &m.workpiece_chain, &errors.workpiece_chain);
    let workpiece = after_workpiece * shape(&m.workpiece) * error(&errors.workpiece_end);
    Ok(Calibrated {
        tool_chain,
        tools,
        workpiece_chain,
        workpiece,
        folded,
        left_out,
    })
}

/// The machine `m` (its bound β) as a URDF robot named `name`: a `base` link, a link per axis
/// (`<axis>_link`) joined by a joint named as the axis, a fixed joint to a link per tool and to
/// a `workpiece` link.
pub fn export(m: &Machine, name: &str) -> Result<Exported, ExportError> {
    let c = calibrated(m)?;
    let mut xml = String::new();
    xml.push_str("<?xml version=\"1.0\"?>\n");
    xml.push_str(&format!(
        "<!-- Written by kin export urdf from machine `{}`: every constant error folded into the \
         joints' origins ({} coefficients); {} --> \n",
        m.name,
        c.folded,
        if c.left_out.is_empty() {
            "no term varies with the pose".to_string()
        } else {
            format!(
                "left out as varying with the pose: {}",
                c.left_out.join(", ")
            )
        }
    ));
    xml.push_str(&format!("<robot name=\"{}\">\n", escape(name)));
    xml.push_str("  <link name=\"base\"/>\n");
    let tool_link = joints_xml(&c.tool_chain, &mut xml)?;
    for (tool, end) in &c.tools {
        fixed(&mut xml, tool, &tool_link, tool, end)?;
    }
    let wp_link = joints_xml(&c.workpiece_chain, &mut xml)?;
    fixed(&mut xml, "workpiece", &wp_link, "workpiece", &c.workpiece)?;
    xml.push_str("</robot>\n");
    Ok(Exported {
        text: xml,
        joints: c.tool_chain.len() + c.workpiece_chain.len(),
        folded: c.folded,
        left_out: c.left_out,
    })
}

fn shape(s: &Shape) -> Matrix4<f64> {
    shape_or_error(s.translation, s.rotation)
}

fn error(e: &[f64; 6]) -> Matrix4<f64> {
    shape_or_error([e[0], e[1], e[2]], [e[3], e[4], e[5]])
}

/// The joints of one chain from the base, and the fixed transform still pending after its last
/// joint's motion (what the chain's end is placed by).
fn chain(
    m: &Machine,
    elements: &[kin_compiler::ir::Element],
    errors: &[[f64; 6]],
) -> (Vec<CalibratedJoint>, Matrix4<f64>) {
    let mut joints = Vec::with_capacity(elements.len());
    let mut pending = Matrix4::<f64>::identity();
    for (k, element) in elements.iter().enumerate() {
        let Some(axis) = m.axes.get(element.axis) else {
            continue;
        };
        let e = errors.get(k).copied().unwrap_or([0.0; 6]);
        let origin = match element.frame {
            FrameKind::Moving => pending * shape(&element.shape),
            FrameKind::Fixed => pending * shape(&element.shape) * error(&e),
        };
        joints.push(CalibratedJoint {
            name: axis.name.clone(),
            kind: axis.kind,
            continuous: axis.continuous,
            range: axis.range,
            origin,
            axis: axis.direction,
        });
        // What follows this joint's motion before the next one: a moving element's error (the
        // motion comes before it), nothing for a fixed one (its error came before the motion).
        pending = match element.frame {
            FrameKind::Moving => error(&e),
            FrameKind::Fixed => Matrix4::identity(),
        };
    }
    (joints, pending)
}

/// Writes the joints of one chain from `base`; returns the last link.
fn joints_xml(joints: &[CalibratedJoint], xml: &mut String) -> Result<String, ExportError> {
    let mut parent = "base".to_string();
    for j in joints {
        let link = format!("{}_link", j.name);
        let kind = match (j.kind, j.continuous) {
            (JointKind::Revolute, true) => "continuous",
            (JointKind::Revolute, false) => "revolute",
            (JointKind::Prismatic, _) => "prismatic",
        };
        xml.push_str(&format!("  <link name=\"{}\"/>\n", escape(&link)));
        xml.push_str(&format!(
            "  <joint name=\"{}\" type=\"{kind}\">\n    <parent link=\"{}\"/>\n    <child link=\"{}\"/>\n",
            escape(&j.name),
            escape(&parent),
            escape(&link)
        ));
        xml.push_str(&origin_xml(&j.origin, &j.name)?);
        let d = j.axis;
        xml.push_str(&format!("    <axis xyz=\"{} {} {}\"/>\n", d[0], d[1], d[2]));
        if !j.continuous {
            // kin knows the range, not the drive: effort and velocity (required by the format)
            // are 0 here and belong to the original description.
            xml.push_str(&format!(
                "    <limit lower=\"{}\" upper=\"{}\" effort=\"0\" velocity=\"0\"/>\n",
                j.range[0], j.range[1]
            ));
        }
        xml.push_str("  </joint>\n");
        parent = link;
    }
    Ok(parent)
}

fn fixed(
    xml: &mut String,
    joint: &str,
    parent: &str,
    child: &str,
    origin: &Matrix4<f64>,
) -> Result<(), ExportError> {
    xml.push_str(&format!("  <link name=\"{}\"/>\n", escape(child)));
    xml.push_str(&format!(
        "  <joint name=\"{}_joint\" type=\"fixed\">\n    <parent link=\"{}\"/>\n    <child link=\"{}\"/>\n",
        escape(joint),
        escape(parent),
        escape(child)
    ));
    xml.push_str(&origin_xml(origin, joint)?);
    xml.push_str("  </joint>\n");
    Ok(())
}

/// `<origin xyz rpy>` of a rigid transform, or the error naming `what` when it is not finite.
fn origin_xml(t: &Matrix4<f64>, what: &str) -> Result<String, ExportError> {
    origin_text(t).ok_or_else(|| ExportError::NotFinite(what.to_string()))
}

/// `<origin xyz rpy>` of a rigid transform: URDF's fixed-axis roll, pitch, yaw
/// (`R = Rz(yaw)·Ry(pitch)·Rx(roll)`), each number in the shortest text that reads back to the
/// same double; `None` when a number is not finite.
pub(crate) fn origin_text(t: &Matrix4<f64>) -> Option<String> {
    let r = Rotation3::from_matrix_unchecked(t.fixed_view::<3, 3>(0, 0).into_owned());
    let (roll, pitch, yaw) = r.euler_angles();
    let values = [t[(0, 3)], t[(1, 3)], t[(2, 3)], roll, pitch, yaw];
    if values.iter().any(|v| !v.is_finite()) {
        return None;
    }
    // `+ 0.0` writes a negative zero as 0.
    let v = values.map(|v| v + 0.0);
    Some(format!(
        "    <origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/>\n",
        v[0], v[1], v[2], v[3], v[4], v[5]
    ))
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pose_dependent_term_is_left_out_by_name() {
        let out = kin_compiler::compile(
            "machine m {
                task position
                units { length mm, angle deg, error um, tilt urad }
                axis J1 revolute about z range -90 deg .. 90 deg
                axis J2 revolute about y continuous
                tool chain { J1 moving  J2 moving at (0, 0, 400) mm  tool t at (300, 0, 0) mm }
                errors { J2.rz = const + cos(J2) * const }
            }",
        );
        let c = out
            .compiled
            .unwrap_or_else(|| panic!("{:?}", out.diagnostics));
        let e = export(&c.machine, "m").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(e.folded, 1);
        assert_eq!(e.joints, 2);
        assert_eq!(e.left_out.len(), 1, "{:?}", e.left_out);
        assert!(e.left_out[0].contains("J2.rz"), "{:?}", e.left_out);
        assert!(e.text.contains("type=\"continuous\""));
        assert!(e.text.contains("<joint name=\"t_joint\" type=\"fixed\">"));
    }
}
