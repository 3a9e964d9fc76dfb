//! The exact simulator: tool locations with the parametric errors applied as finite transforms
//! (eq. 2.8 without its first-order approximation), for generating synthetic measurements and
//! for checking the first-order model in [`crate::kinematics`].
//!
//! It deliberately shares no formula with the first-order code: it applies the moving/fixed
//! table of eq. 2.35–2.38 step by step, builds rotations from elementary matrices and a basis
//! rather than in closed form, and reads errors off the actual transform with the rotation log
//! map. Only the input types and the error enum are shared.
//!
//! All errors returned are *positioning* errors (actual − nominal, spec/kinematics.md); apply
//! [`task_error`] for the reported sign.

use kin_compiler::ir::{Element, FrameKind, JointKind, Machine, Shape};
use nalgebra::{Matrix3, Matrix4, Vector3, Vector6};

pub use crate::kinematics::task_error;
use crate::kinematics::{check_pose, Chain, FrameErrors, KinematicsError, Pose};

/// The nominal location `T(wr→tl) = T(0→wr)⁻¹ · T(0→tl)` of the tool frame at `pose`
/// (eq. 2.6–2.7, spec/kinematics.md).
pub fn nominal_transform(
    machine: &Machine,
    pose: &Pose<'_>,
) -> Result<Matrix4<f64>, KinematicsError> {
    check_pose(machine, pose)?;
    relative_location(machine, pose, None)
}

/// The actual location `T(wr→tl)` at `pose` with every step followed by its parametric error
/// (eq. 2.8, 2.13), exactly.
pub fn actual_transform(
    machine: &Machine,
    pose: &Pose<'_>,
    errors: &FrameErrors,
) -> Result<Matrix4<f64>, KinematicsError> {
    check_pose(machine, pose)?;
    errors.check(machine)?;
    relative_location(machine, pose, Some(errors))
}

/// The exact positioning error `(ex, ey, ez, erx, ery, erz)` at `pose` (spec/kinematics.md): the
/// translation of the actual `T(wr→tl)` minus the nominal one, and the rotation vector `r` of
/// `R_act·R_nomᵀ`, both in wr axes.
pub fn positioning_error(
    machine: &Machine,
    pose: &Pose<'_>,
    errors: &FrameErrors,
) -> Result<Vector6<f64>, KinematicsError> {
    let nominal = nominal_transform(machine, pose)?;
    let actual = actual_transform(machine, pose, errors)?;
    Ok(location_error(&nominal, &actual))
}

/// The exact length error between two poses, positioning sign (spec/data.md):
/// `|p2_act − p1_act| − |p2_nom − p1_nom|`, where `p_act` is the tool origin in the *actual*
/// wr frame of its pose and `p_nom` in the nominal one. Each end is expressed in its own pose's
/// wr frame because the measured object rides with the workpiece, whatever the table did
/// between the poses. Eq. 4.5 is the first-order approximation of this.
pub fn length_error(
    machine: &Machine,
    pose1: &Pose<'_>,
    errors1: &FrameErrors,
    pose2: &Pose<'_>,
    errors2: &FrameErrors,
) -> Result<f64, KinematicsError> {
    let origin = |t: &Matrix4<f64>| -> Vector3<f64> { t.fixed_view::<3, 1>(0, 3).into_owned() };
    let n1 = origin(&nominal_transform(machine, pose1)?);
    let n2 = origin(&nominal_transform(machine, pose2)?);
    let a1 = origin(&actual_transform(machine, pose1, errors1)?);
    let a2 = origin(&actual_transform(machine, pose2, errors2)?);
    Ok((a2 - a1).norm() - (n2 - n1).norm())
}

/// The error of `actual` relative to `nominal`, both `T(wr→tl)`, as spec/kinematics.md defines it.
pub fn location_error(nominal: &Matrix4<f64>, actual: &Matrix4<f64>) -> Vector6<f64> {
    let dp = actual.fixed_view::<3, 1>(0, 3) - nominal.fixed_view::<3, 1>(0, 3);
    let r_nom = nominal.fixed_view::<3, 3>(0, 0);
    let r_act = actual.fixed_view::<3, 3>(0, 0);
    let r = rotation_vector(&(r_act * r_nom.transpose()));
    Vector6::new(dp[0], dp[1], dp[2], r[0], r[1], r[2])
}

/// The rotation vector (axis · angle, angle in `[0, π]`) of a rotation matrix: the log map,
/// so that `R = exp([r]×)`. Exact for any angle, not only small ones.
pub(crate) fn rotation_vector(r: &Matrix3<f64>) -> Vector3<f64> {
    // v = sin θ · axis, from the antisymmetric part.
    let v = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    ) * 0.5;
    let s = v.norm();
    let c = ((r.trace() - 1.0) * 0.5).clamp(-1.0, 1.0);
    let angle = libm::atan2(s, c);
    if c > -0.5 {
        // θ/sin θ by its series where the quotient would lose digits (error ~θ⁴/400).
        let factor = if angle < 1e-4 {
            1.0 + angle * angle / 6.0
        } else {
            angle / s
        };
        return v * factor;
    }
    // Near π, sin θ is too small to divide by; the symmetric part is (1 − cos θ)·a·aᵀ.
    let b = (r + r.transpose()) * 0.5 - Matrix3::identity() * c;
    let mut i = 0;
    for k in 1..3 {
        if b[(k, k)] > b[(i, i)] {
            i = k;
        }
    }
    let column = b.column(i).into_owned();
    let n = column.norm();
    if n == 0.0 {
        return Vector3::zeros();
    }
    let axis = column / n;
    let axis = if axis.dot(&v) < 0.0 { -axis } else { axis };
    axis * angle
}

/// `T(wr→tl)` with or without errors: `T(0→wr)⁻¹ · T(0→tl)` (spec/kinematics.md).
fn relative_location(
    machine: &Machine,
    pose: &Pose<'_>,
    errors: Option<&FrameErrors>,
) -> Result<Matrix4<f64>, KinematicsError> {
    let tool = machine
        .tools
        .get(pose.tool)
        .ok_or(KinematicsError::ToolIndex {
            index: pose.tool,
            count: machine.tools.len(),
        })?;
    let tool_shape = Shape {
        translation: pose.tool_offset.unwrap_or(tool.offset.translation),
        rotation: tool.offset.rotation,
    };
    let to_tool = base_to_end(
        machine,
        Chain::Tool,
        &machine.tool_chain,
        &tool_shape,
        pose.q,
        errors.map(|e| (e.tool_chain.as_slice(), &e.tool_end)),
    )?;
    let to_wr = base_to_end(
        machine,
        Chain::Workpiece,
        &machine.workpiece_chain,
        &machine.workpiece,
        pose.q,
        errors.map(|e| (e.workpiece_chain.as_slice(), &e.workpiece_end)),
    )?;
    Ok(rigid_inverse(&to_wr) * to_tool)
}

/// `T(0→end)` of one chain, multiplying the steps of the table of eq. 2.35–2.38 from the base
/// out (the base counts as moving), each followed by its error transform when given (eq. 2.8).
fn base_to_end(
    machine: &Machine,
    chain: Chain,
    elements: &[Element],
    end: &Shape,
    q: &[f64],
    errors: Option<(&[[f64; 6]], &[f64; 6])>,
) -> Result<Matrix4<f64>, KinematicsError> {
    let mut location = Matrix4::<f64>::identity();
    // J_{k-1} when frame k-1 is fixed: its motion belongs to the next step.
    let mut carried: Option<Matrix4<f64>> = None;
    for (k, element) in elements.iter().enumerate() {
        let bad_axis = KinematicsError::AxisIndex {
            chain,
            element: k,
            axis: element.axis,
            count: machine.axes.len(),
        };
        let axis = machine.axes.get(element.axis).ok_or(bad_axis.clone())?;
        let qk = *q.get(element.axis).ok_or(bad_axis)?;
        let joint = joint_motion(axis.kind, axis.direction, qk);
        let shape = shape_or_error(element.shape.translation, element.shape.rotation);
        let mut step = match carried.take() {
            Some(previous) => previous * shape,
            None => shape,
        };
        match element.frame {
            FrameKind::Moving => step *= joint,
            FrameKind::Fixed => carried = Some(joint),
        }
        if let Some(e) = errors.and_then(|(chain_errors, _)| chain_errors.get(k)) {
            step *= error_transform(e);
        }
        location *= step;
    }
    let shape = shape_or_error(end.translation, end.rotation);
    let mut step = match carried {
        Some(previous) => previous * shape,
        None => shape,
    };
    if let Some((_, e)) = errors {
        step *= error_transform(e);
    }
    Ok(location * step)
}

/// The actual-over-nominal transform of eq. 2.8, exactly:
/// `Trans(tx, ty, tz)·Rot_x(rx)·Rot_y(ry)·Rot_z(rz)`.
fn error_transform(e: &[f64; 6]) -> Matrix4<f64> {
    shape_or_error([e[0], e[1], e[2]], [e[3], e[4], e[5]])
}

/// `Trans(t)·Rot_x(r_x)·Rot_y(r_y)·Rot_z(r_z)` as a product of elementary transforms: the
/// form of both a shape transform (spec/kinematics.md) and an error transform (eq. 2.8).
pub fn shape_or_error(t: [f64; 3], r: [f64; 3]) -> Matrix4<f64> {
    let mut translation = Matrix4::identity();
    translation[(0, 3)] = t[0];
    translation[(1, 3)] = t[1];
    translation[(2, 3)] = t[2];
    translation
        * elementary_rotation(0, r[0])
        * elementary_rotation(1, r[1])
        * elementary_rotation(2, r[2])
}

/// Rotation by `angle` about base axis `axis` (0 = x, 1 = y, 2 = z), right-handed.
fn elementary_rotation(axis: usize, angle: f64) -> Matrix4<f64> {
    let (s, c) = (libm::sin(angle), libm::cos(angle));
    // The two axes that turn, in cyclic order after `axis`.
    let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut m = Matrix4::identity();
    m[(i, i)] = c;
    m[(i, j)] = -s;
    m[(j, i)] = s;
    m[(j, j)] = c;
    m
}

/// The nominal joint motion `J(q)` (spec/kinematics.md). A rotation is built in an orthonormal basis
/// `(u, v, w)` with `w = u × v`: `u uᵀ + cos q (v vᵀ + w wᵀ) + sin q (w vᵀ − v wᵀ)`, which
/// turns `v` towards `w` as a right-handed rotation about `u` must.
fn joint_motion(kind: JointKind, direction: [f64; 3], q: f64) -> Matrix4<f64> {
    let u = Vector3::from(direction);
    let mut m = Matrix4::identity();
    match kind {
        JointKind::Prismatic => {
            m.fixed_view_mut::<3, 1>(0, 3).copy_from(&(u * q));
        }
        JointKind::Revolute => {
            // Cross with the base axis least aligned with u to get a well-conditioned normal.
            let a = u.map(f64::abs);
            let helper = if a.x <= a.y && a.x <= a.z {
                Vector3::x()
            } else if a.y <= a.z {
                Vector3::y()
            } else {
                Vector3::z()
            };
            let v = u.cross(&helper).normalize();
            let w = u.cross(&v);
            let (s, c) = (libm::sin(q), libm::cos(q));
            let r = u * u.transpose()
                + (v * v.transpose() + w * w.transpose()) * c
                + (w * v.transpose() - v * w.transpose()) * s;
            m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        }
    }
    m
}

/// Inverse of a rigid transform (eq. 2.5): `[Rᵀ, −Rᵀt]`, exact where a general inverse
/// would round.
fn rigid_inverse(t: &Matrix4<f64>) -> Matrix4<f64> {
    let rt = t.fixed_view::<3, 3>(0, 0).transpose();
    let p = -(rt * t.fixed_view::<3, 1>(0, 3));
    let mut inv = Matrix4::identity();
    inv.fixed_view_mut::<3, 3>(0, 0).copy_from(&rt);
    inv.fixed_view_mut::<3, 1>(0, 3).copy_from(&p);
    inv
}

#[cfg(test)]
mod tests {
    use kin_compiler::ir::{FrameKind, JointKind, Task};
    use nalgebra::{Matrix3, Rotation3, Vector3, Vector6};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    use super::*;
    use crate::kinematics::testing::*;

    const ZERO: [f64; 3] = [0.0; 3];

    fn pose(q: &[f64]) -> Pose<'_> {
        Pose {
            q,
            tool: 0,
            tool_offset: None,
        }
    }

    #[test]
    fn rotation_vector_inverts_the_exponential_at_every_angle() {
        let mut rng = StdRng::seed_from_u64(5);
        let angles = [
            0.0,
            1e-12,
            1e-7,
            1e-4,
            0.3,
            2.0,
            3.0,
            std::f64::consts::PI - 1e-9,
        ];
        for angle in angles {
            for _ in 0..50 {
                let axis = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize();
                let r = Rotation3::from_scaled_axis(axis * angle).into_inner();
                let got = rotation_vector(&r);
                assert!(
                    (got - axis * angle).amax() < 1e-9 * (1.0 + angle),
                    "{angle}: {got} vs {}",
                    axis * angle
                );
            }
        }
        assert_eq!(rotation_vector(&Matrix3::identity()), Vector3::zeros());
    }

    #[test]
    fn elementary_rotations_are_right_handed() {
        let quarter = std::f64::consts::FRAC_PI_2;
        // Rot_z(90°) takes x to y, Rot_x takes y to z, Rot_y takes z to x.
        for (axis, from, to) in [(2, 0, 1), (0, 1, 2), (1, 2, 0)] {
            let r = elementary_rotation(axis, quarter);
            assert!((r[(to, from)] - 1.0).abs() < 1e-15);
        }
        // The joint rotation about a base axis equals the elementary one.
        for (axis, dir) in [
            (0, [1.0, 0.0, 0.0]),
            (1, [0.0, 1.0, 0.0]),
            (2, [0.0, 0.0, 1.0]),
        ] {
            let j = joint_motion(JointKind::Revolute, dir, 0.7);
            assert!((j - elementary_rotation(axis, 0.7)).amax() < 1e-15);
        }
    }

    #[test]
    fn large_rz_error_is_applied_exactly() {
        // A 0.1 rad rz of the X carriage swings the probe at (0, l, 0) on a circle:
        // (−l sin rz, l cos rz − l, 0), and turns it by exactly rz.
        let l = 0.25;
        let m = machine(
            Task::Position,
            vec![axis("X", JointKind::Prismatic, [1.0, 0.0, 0.0])],
            vec![element(0, FrameKind::Moving, shape(ZERO, ZERO))],
            vec![],
            vec![tool("t", shape([0.0, l, 0.0], ZERO))],
            shape(ZERO, ZERO),
        );
        let rz = 0.1;
        let mut errors = FrameErrors::zeros(&m);
        errors.tool_chain[0][5] = rz;
        let e = positioning_error(&m, &pose(&[0.4]), &errors).unwrap();
        let expected = Vector6::new(-l * rz.sin(), l * rz.cos() - l, 0.0, 0.0, 0.0, rz);
        assert!((e - expected).amax() < 1e-15, "{e}");
    }

    #[test]
    fn error_transform_translates_before_rotating() {
        // Eq. 2.8: Trans then rotations, so the translation is along the *unrotated* axes and a
        // tool offset from the frame is turned by the rotation.
        let m = machine(
            Task::Position,
            vec![],
            vec![],
            vec![],
            vec![tool("t", shape([0.0, 0.0, 0.0], ZERO))],
            shape(ZERO, ZERO),
        );
        let mut errors = FrameErrors::zeros(&m);
        errors.tool_end = [0.1, 0.0, 0.0, 0.0, 0.0, std::f64::consts::FRAC_PI_2];
        let t = actual_transform(&m, &pose(&[]), &errors).unwrap();
        assert!((t.fixed_view::<3, 1>(0, 3) - Vector3::new(0.1, 0.0, 0.0)).amax() < 1e-15);
        assert!((t[(1, 0)] - 1.0).abs() < 1e-15);
    }

    #[test]
    fn fixed_frame_carries_its_joint_into_the_next_step() {
        // Table rule: after a fixed frame, T(k→k+1) = J_k·S_{k+1}·J_{k+1}. A fixed revolute B
        // about y at the base followed by a moving Z slide at (0, 0, 0.5): Z's shape offset and
        // its travel both turn with B.
        let m = machine(
            Task::Position,
            vec![
                axis("B", JointKind::Revolute, [0.0, 1.0, 0.0]),
                axis("Z", JointKind::Prismatic, [0.0, 0.0, 1.0]),
            ],
            vec![
                element(0, FrameKind::Fixed, shape(ZERO, ZERO)),
                element(1, FrameKind::Moving, shape([0.0, 0.0, 0.5], ZERO)),
            ],
            vec![],
            vec![tool("t", shape(ZERO, ZERO))],
            shape(ZERO, ZERO),
        );
        let b = 0.4;
        let t = nominal_transform(&m, &pose(&[b, 0.1])).unwrap();
        let expected = Vector3::new(b.sin(), 0.0, b.cos()) * 0.6;
        assert!((t.fixed_view::<3, 1>(0, 3) - expected).amax() < 1e-15);

        // An error of the fixed B frame acts before J_B: a tz error moves the tool along base z,
        // not along the turned z.
        let mut errors = FrameErrors::zeros(&m);
        errors.tool_chain[0][2] = 1e-3;
        let e = positioning_error(&m, &pose(&[b, 0.1]), &errors).unwrap();
        assert!((e - Vector6::new(0.0, 0.0, 1e-3, 0.0, 0.0, 0.0)).amax() < 1e-15);
    }

    #[test]
    fn exact_length_error_of_a_scale_error() {
        // A uniform scale error s of a single X slide (X.tx = s·x) stretches every length
        // along x by exactly s·L.
        let m = machine(
            Task::Measure,
            vec![axis("X", JointKind::Prismatic, [1.0, 0.0, 0.0])],
            vec![element(0, FrameKind::Moving, shape(ZERO, ZERO))],
            vec![],
            vec![tool("t", shape([0.0, 0.1, 0.0], ZERO))],
            shape(ZERO, ZERO),
        );
        let s = 1e-4;
        let errs = |x: f64| {
            let mut e = FrameErrors::zeros(&m);
            e.tool_chain[0][0] = s * x;
            e
        };
        let dl = length_error(&m, &pose(&[-0.2]), &errs(-0.2), &pose(&[0.3]), &errs(0.3)).unwrap();
        assert!((dl - s * 0.5).abs() < 1e-15);
        assert!((task_error(m.task, &Vector6::repeat(dl))[0] + s * 0.5).abs() < 1e-15);
    }
}
