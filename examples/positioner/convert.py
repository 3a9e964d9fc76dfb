#!/usr/bin/env python3
"""Convert the ros-industrial `industrial_calibration` two-axis positioner data
(examples/data/kinematic_calibration/measurements.yaml, commit fe62b7c9) into kin's formats.

Writes into OUTDIR (default: the directory of this script):
  positioner.kin          the machine and its base error model (the 14 constant location errors)
  data/all.csv            205 poses, 6-DoF deviations (actual - nominal) of the camera->target pose
  data/foldA.csv          even-indexed poses (0, 2, 4, ... in the file's time order)
  data/foldB.csv          odd-indexed poses
  data/halfA.csv, halfB.csv  first / second half in time (secondary split)
  registration.json       the camera and target transforms estimated here (outside kin) and the
                          linearisation point's numbers
  reference_cv.json       2-fold CV of a re-implementation of the reference's own model (nonlinear
                          DH calibration, its cost), for comparison with kin

Reference model (examples/kinematic_calibration.cpp):
  camera_to_target = camera_mount_to_camera^-1 * base_offset * DH(j1) * DH(j2) * target_mount_to_target
  base_offset = Trans(2.2, 0, 1.6) m * Rot_x(90 deg)
  DH(d, theta, r, alpha) = Trans_z(d) Rot_z(theta) Trans_x(r) Rot_x(alpha)
  joint 1: (0, j1, 0, -90 deg), joint 2: (-0.475 m, j2 - 90 deg, 0, 0)
Only numpy and the standard library are used.
"""
import json
import math
import os
import re
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


# ---------------------------------------------------------------- small SE(3) helpers
def rotx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def roty(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rotz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def hom(R=None, t=None):
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def inv(T):
    R, t = T[:3, :3], T[:3, 3]
    return hom(R.T, -R.T @ t)


def skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def expso3(w):
    th = np.linalg.norm(w)
    if th < 1e-12:
        return np.eye(3) + skew(w)
    k = w / th
        # Rodrigues
    K = skew(k)
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def logso3(R):
    c = max(-1.0, min(1.0, (np.trace(R) - 1) / 2))
    th = math.acos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-9:
        return v / 2
    return v * th / (2 * math.sin(th))


def quat_to_R(qw, qx, qy, qz):
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    qw, qx, qy, qz = qw / n, qx / n, qy / n, qz / n
    return np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ])


def R_to_xyz(R):
    """R = Rot_x(a) Rot_y(b) Rot_z(c) (kin's `rot (a, b, c)`), angles in rad."""
    b = math.asin(max(-1.0, min(1.0, R[0, 2])))
    a = math.atan2(-R[1, 2], R[2, 2])
    c = math.atan2(-R[0, 1], R[0, 0])
    return a, b, c


def xyz_to_R(a, b, c):
    return rotx(a) @ roty(b) @ rotz(c)


def pose_vec(T):
    """(t, rotation vector) of a transform: the 6 parameters the GN fits below use."""
    return np.concatenate([T[:3, 3], logso3(T[:3, :3])])


def vec_pose(p):
    return hom(expso3(p[3:6]), p[0:3])


# ---------------------------------------------------------------- the reference's model
def dh(d, th, r, al):
    return hom(None, [0, 0, d]) @ hom(rotz(th)) @ hom(None, [r, 0, 0]) @ hom(rotx(al))


BASE = hom(rotx(math.pi / 2), [2.2, 0.0, 1.6])
DH_NOM = np.array([[0.0, 0.0, 0.0, -math.pi / 2], [-0.475, -math.pi / 2, 0.0, 0.0]])


def fk(j, off1=np.zeros(4)):
    p1 = DH_NOM[0] + off1
    p2 = DH_NOM[1]
    return BASE @ dh(p1[0], p1[1] + j[0], p1[2], p1[3]) @ dh(p2[0], p2[1] + j[1], p2[2], p2[3])


# ---------------------------------------------------------------- data
def load_measurements(path):
    """The YAML file is regular (key, camera_joints, pose{qw..z}, target_joints list): parsed by hand."""
    recs = []
    cur = None
    mode = None
    for line in open(path):
        line = line.rstrip("\n")
        m = re.match(r"^'?(\d+)'?:\s*$", line)
        if m:
            cur = {"stamp": m.group(1), "pose": {}, "joints": []}
            recs.append(cur)
            mode = None
            continue
        s = line.strip()
        if s.startswith("camera_joints"):
            mode = None
        elif s.startswith("pose:"):
            mode = "pose"
        elif s.startswith("target_joints"):
            mode = "joints"
        elif s.startswith("- ") and mode == "joints":
            cur["joints"].append(float(s[2:]))
        elif mode == "pose" and ":" in s:
            k, v = s.split(":", 1)
            cur["pose"][k.strip()] = float(v)
    out = []
    for r in recs:
        p = r["pose"]
        T = hom(quat_to_R(p["qw"], p["qx"], p["qy"], p["qz"]), [p["x"], p["y"], p["z"]])
        out.append((r["stamp"], np.array(r["joints"]), T))
    return out


def load_guesses(path):
    d = {}
    cur = None
    for line in open(path):
        if not line.strip():
            continue
        if not line.startswith(" "):
            cur = line.split(":")[0].strip()
            d[cur] = {}
        else:
            k, v = line.split(":")
            d[cur][k.strip()] = float(v)
    g = {}
    for k, p in d.items():
        g[k] = hom(quat_to_R(p["qw"], p["qx"], p["qy"], p["qz"]), [p["x"], p["y"], p["z"]])
    return g


# ---------------------------------------------------------------- nonlinear fits (outside kin)
def residuals(params, meas, wrot, n_dh, ref_translation=False):
    """params: W->C (6), F->T (6), then n_dh DH offsets of joint 1 in the order the mask leaves.
    ref_translation: the reference's cost (DualDHChainMeasurementCost): the translation of
    T_meas * T_pred^-1, i.e. t_meas - R_err t_pred, which adds (rotation error) x t_pred to the
    position residual; otherwise the plain difference t_meas - t_pred (kin's position error)."""
    WC = vec_pose(params[0:6])
    FT = vec_pose(params[6:12])
    off = np.zeros(4)
    if n_dh == 4:
        off = params[12:16]
    elif n_dh == 2:   # r1, alpha1 only (d1, theta1 duplicate the camera transform)
        off = np.array([0.0, 0.0, params[12], params[13]])
    iWC = inv(WC)
    res = []
    for _, j, Tm in meas:
        Tp = iWC @ fk(j, off) @ FT
        Rerr = Tm[:3, :3] @ Tp[:3, :3].T
        dp = Tm[:3, 3] - (Rerr @ Tp[:3, 3] if ref_translation else Tp[:3, 3])
        dr = logso3(Rerr)
        res.append(np.concatenate([dp, wrot * dr]))
    return np.concatenate(res)


def gauss_newton(p0, meas, wrot, n_dh, prior_sd=None, iters=50, reft=False):
    p = p0.copy()
    for it in range(iters):
        r = residuals(p, meas, wrot, n_dh, reft)
        J = np.empty((r.size, p.size))
        for k in range(p.size):
            h = 1e-7
            dp = np.zeros_like(p)
            dp[k] = h
            J[:, k] = (residuals(p + dp, meas, wrot, n_dh, reft) - residuals(p - dp, meas, wrot, n_dh, reft)) / (2 * h)
        # residual is measured - predicted: d r / d p = -d pred / d p; GN on min |r|^2
        if prior_sd is not None and n_dh:
            # the reference's MaximumLikelihood cost on the DH offsets: (offset - 0) / sd
            Jp = np.zeros((n_dh, p.size))
            Jp[:, 12:12 + n_dh] = np.eye(n_dh) / prior_sd
            rp = p[12:12 + n_dh] / prior_sd
            J = np.vstack([J, Jp])
            r = np.concatenate([r, rp])
        step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        p = p + step
        if np.max(np.abs(step)) < 1e-12:
            break
    return p


def fold_stats(params, meas, n_dh):
    r = residuals(params, meas, 1.0, n_dh).reshape(-1, 6)
    pos = r[:, :3] * 1e6   # um
    rot = r[:, 3:] * 1e6   # urad
    return {
        "n": len(meas),
        "pos_rms_um": float(np.sqrt(np.mean(pos ** 2))),              # RMS over every ex, ey, ez value
        "pos_norm_rms_um": float(np.sqrt(np.mean(np.sum(pos ** 2, 1)))),  # RMS of the 3-D distance
        "pos_norm_mean_um": float(np.mean(np.linalg.norm(pos, axis=1))),  # the reference's statistic
        "rot_rms_urad": float(np.sqrt(np.mean(rot ** 2))),
        "rot_norm_rms_urad": float(np.sqrt(np.mean(np.sum(rot ** 2, 1)))),
        "rot_norm_mean_urad": float(np.mean(np.linalg.norm(rot, axis=1))),
        "pos_rms_xyz_um": [float(x) for x in np.sqrt(np.mean(pos ** 2, 0))],
        "rot_rms_xyz_urad": [float(x) for x in np.sqrt(np.mean(rot ** 2, 0))],
    }


# ---------------------------------------------------------------- output
def fmt(x, nd=9):
    s = f"{x:.{nd}f}"
    if s.startswith("-") and float(s) == 0.0:
        s = s[1:]
    return s


def write_csv(path, meas, WC, FT, header_comment):
    """6-DoF deviations, kin's convention (spec/kinematics.md, task position):
    e = p_actual - p_nominal in wr (camera) axes; R_actual = (I + [r]x) R_nominal, r in wr axes."""
    iWC = inv(WC)
    with open(path, "w") as f:
        for c in header_comment:
            f.write(f"# {c}\n")
        f.write("stamp,J1[rad],J2[rad],ex[um],ey[um],ez[um],erx[urad],ery[urad],erz[urad]\n")
        for stamp, j, Tm in meas:
            Tn = iWC @ fk(j) @ FT
            dp = (Tm[:3, 3] - Tn[:3, 3]) * 1e6
            dr = logso3(Tm[:3, :3] @ Tn[:3, :3].T) * 1e6
            f.write(",".join([stamp, repr(float(j[0])), repr(float(j[1]))]
                             + [f"{v:.3f}" for v in dp] + [f"{v:.3f}" for v in dr]) + "\n")


KIN_TEMPLATE = """// Two-axis part positioner of ros-industrial `industrial_calibration`
// (examples/kinematic_calibration.cpp, data examples/data/kinematic_calibration, commit fe62b7c9),
// observed by a fixed 3-D camera as 6-DoF poses of a target mounted on the positioner's plate.
// Generated by examples/positioner/convert.py -- edit the script, not this file.
//
// kin's view: the positioner is the TOOL chain (J1, J2 carry the target = the tool frame), and
// the WORKPIECE reference frame is the camera (a chain with no joint). The observed error is then
// exactly the camera->target pose (spec/kinematics.md). Nominal geometry: the reference's DH
// chain, base_offset = Trans(2.2, 0, 1.6) m * Rot_x(90 deg), joint 1 DH (d 0, theta 0, r 0,
// alpha -90 deg), joint 2 DH (d -0.475 m, theta -90 deg, r 0, alpha 0), rewritten as kin shapes:
//   J1: at (2200, 0, 1600) mm rot (90, 0, 0) deg     (= base_offset)
//   J2: at (0, -475, 0) mm rot (-90, 0, -90) deg     (= Rot_x(-90) Trans_z(-475) Rot_z(-90))
// The camera (world->camera) and the target (plate->target) transforms are NOT given by the
// reference; they were estimated outside kin by convert.py (Gauss-Newton on all 205 poses with
// the nominal DH chain, i.e. the reference's "static DH" calibration) and serve as the
// linearisation point. Their errors are refitted here as the constants workpiece.* and target.*.
machine positioner_2axis {
    task position
    units { length mm, angle deg, error um, tilt urad }
    gravity along -z        // the reference's world frame has z up: J1 tilts the plate

    axis J1 revolute about z range -180 deg .. 180 deg   // tilt
    axis J2 revolute about z continuous                 // rotary plate

    tool chain {
        J1 moving at (2200, 0, 1600) mm rot (90, 0, 0) deg
        J2 moving at (0, -475, 0) mm rot (-90, 0, -90) deg
        tool target at (%(ft_t)s) mm rot (%(ft_r)s) deg
    }
    workpiece chain {
        workpiece at (%(wc_t)s) mm rot (%(wc_r)s) deg   // the camera
    }

    // The constant location errors a calibrator starts with: complete and minimal for two
    // revolute axes observed as full poses (4 R + 6 = 14; the reference fits the same set as
    // camera 6 + target 6 + joint-1 DH r, alpha; its d1, theta1 duplicate the camera).
    errors {
        // camera (workpiece reference) placement: also J1's axis location and zero
        workpiece.tx = const
        workpiece.ty = const
        workpiece.tz = const
        workpiece.rx = const
        workpiece.ry = const
        workpiece.rz = const
        // J2's axis relative to J1's: offset along the common normal (DH r1) and twist (DH alpha1)
        J1.tx = const
        J1.rx = const
        // target on the plate: also J2's zero and its axial position
        target.tx = const
        target.ty = const
        target.tz = const
        target.rx = const
        target.ry = const
        target.rz = const
    }
}
"""


def main():
    src = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "measurements.yaml")
    guesses = sys.argv[2] if len(sys.argv) > 2 else os.path.join(HERE, "pose_initial_guesses.yaml")
    outdir = sys.argv[3] if len(sys.argv) > 3 else HERE
    os.makedirs(os.path.join(outdir, "data"), exist_ok=True)

    meas = load_measurements(src)
    stamps = [m[0] for m in meas]
    assert stamps == sorted(stamps, key=int), "file not in time order"
    g = load_guesses(guesses)

    # 1. registration outside kin: W->C and F->T with the nominal DH chain (reference: "static DH")
    p0 = np.concatenate([pose_vec(g["camera_mount_to_camera_guess"]), pose_vec(g["target_mount_to_target_guess"])])
    p_reg = gauss_newton(p0, meas, 1.0, 0)
    WC, FT = vec_pose(p_reg[0:6]), vec_pose(p_reg[6:12])

    # round to what the .kin file holds, and use exactly those numbers for the nominal
    def kin_numbers(T):
        t = [round(v * 1000, 6) for v in T[:3, 3]]
        r = [round(math.degrees(a), 9) for a in R_to_xyz(T[:3, :3])]
        Tr = hom(xyz_to_R(*[math.radians(a) for a in r]), [v / 1000 for v in t])
        return t, r, Tr
    wc_t, wc_r, WC = kin_numbers(WC)
    ft_t, ft_r, FT = kin_numbers(FT)

    kin = KIN_TEMPLATE % {
        "wc_t": ", ".join(fmt(v, 6) for v in wc_t), "wc_r": ", ".join(fmt(v, 9) for v in wc_r),
        "ft_t": ", ".join(fmt(v, 6) for v in ft_t), "ft_r": ", ".join(fmt(v, 9) for v in ft_r),
    }
    with open(os.path.join(outdir, "positioner.kin"), "w") as f:
        f.write(kin)

    common = [
        "ros-industrial/industrial_calibration@fe62b7c9b7b347ee047a6fee6f417cd8427b2836",
        "examples/data/kinematic_calibration/measurements.yaml, converted by examples/positioner/convert.py",
        "deviation of the measured camera->target pose from positioner.kin's nominal (actual - nominal),",
        "positions in the camera frame (um), rotation vector r with R_meas = exp([r]x) R_nom (urad, camera axes)",
        "stamp: the YAML key (unix time of the observation); not a kin column, read with --ignore stamp",
    ]
    write_csv(os.path.join(outdir, "data", "all.csv"), meas, WC, FT, common + ["all 205 poses"])
    A = meas[0::2]
    B = meas[1::2]
    write_csv(os.path.join(outdir, "data", "foldA.csv"), A, WC, FT, common + ["fold A: poses 0, 2, 4, ... (even index, time order)"])
    write_csv(os.path.join(outdir, "data", "foldB.csv"), B, WC, FT, common + ["fold B: poses 1, 3, 5, ... (odd index, time order)"])
    # secondary split: first / second half in time (J1 from -30 to about 0 deg, then on to +30 deg):
    # each fold predicts J1 angles it never saw (extrapolation), a harder test than alternation
    h = (len(meas) + 1) // 2
    write_csv(os.path.join(outdir, "data", "halfA.csv"), meas[:h], WC, FT, common + [f"half A: poses 0 .. {h - 1} (first half in time)"])
    write_csv(os.path.join(outdir, "data", "halfB.csv"), meas[h:], WC, FT, common + [f"half B: poses {h} .. {len(meas) - 1} (second half in time)"])

    # 2. the reference's own model, re-implemented, with 2-fold CV (for comparison with kin)
    ref = {}
    variants = {
        # the reference's example: orientation weight 100 (m per rad), DH offsets of joint 1 free
        # (the second row masked) with the MaximumLikelihood prior sd 0.005, camera + target free
        "reference_cost_w100_prior": dict(wrot=100.0, n_dh=4, prior=0.005, reft=True),
        # plain least squares, 1 m per rad (1 mrad ~ 1 mm), the minimal 14 parameters, no prior
        "ls_w1_14p": dict(wrot=1.0, n_dh=2, prior=None, reft=False),
        # static DH (camera + target only), orientation weight 100: the reference's "before" model
        "static_dh_w100": dict(wrot=100.0, n_dh=0, prior=None, reft=True),
    }
    h = (len(meas) + 1) // 2
    splits = {"alternate": (A, B), "half": (meas[:h], meas[h:])}
    for name, v in variants.items():
        def fit(train):
            p = np.concatenate([p_reg, np.zeros(v["n_dh"])])
            return gauss_newton(p, train, v["wrot"], v["n_dh"], v["prior"], reft=v["reft"])
        pall = fit(meas)
        ref[name] = {"settings": v, "fit_all_on_all": fold_stats(pall, meas, v["n_dh"]),
                     "dh_offsets_all": [float(x) for x in pall[12:]]}
        for sname, (SA, SB) in splits.items():
            pA, pB = fit(SA), fit(SB)
            pre = "" if sname == "alternate" else "half_"
            ref[name][pre + "fit_A_predict_B"] = fold_stats(pA, SB, v["n_dh"])
            ref[name][pre + "fit_B_predict_A"] = fold_stats(pB, SA, v["n_dh"])
            ref[name][pre + "fit_A_on_A"] = fold_stats(pA, SA, v["n_dh"])
            ref[name][pre + "fit_B_on_B"] = fold_stats(pB, SB, v["n_dh"])
            # combined CV: pool the held-out residuals
            rA = residuals(pB, SA, 1.0, v["n_dh"]).reshape(-1, 6) * 1e6
            rB = residuals(pA, SB, 1.0, v["n_dh"]).reshape(-1, 6) * 1e6
            rr = np.vstack([rA, rB])
            ref[name][pre + "cv_combined"] = {
                "pos_rms_um": float(np.sqrt(np.mean(rr[:, :3] ** 2))),
                "pos_norm_rms_um": float(np.sqrt(np.mean(np.sum(rr[:, :3] ** 2, 1)))),
                "rot_rms_urad": float(np.sqrt(np.mean(rr[:, 3:] ** 2))),
                "rot_norm_rms_urad": float(np.sqrt(np.mean(np.sum(rr[:, 3:] ** 2, 1)))),
            }
    with open(os.path.join(outdir, "reference_cv.json"), "w") as f:
        json.dump(ref, f, indent=1)

    reg_stats = fold_stats(p_reg, meas, 0)
    with open(os.path.join(outdir, "registration.json"), "w") as f:
        json.dump({
            "method": "Gauss-Newton (numerical Jacobian) from the reference's pose_initial_guesses.yaml, "
                      "nominal DH chain, residual (position m, rotation vector rad x 1 m), all 205 poses",
            "world_to_camera": {"t_mm": wc_t, "rot_xyz_deg": wc_r, "matrix": WC.tolist()},
            "plate_to_target": {"t_mm": ft_t, "rot_xyz_deg": ft_r, "matrix": FT.tolist()},
            "residual_at_linearisation_point": reg_stats,
        }, f, indent=1)
    print(f"poses: {len(meas)}  fold A: {len(A)}  fold B: {len(B)}")
    print(f"registration (static DH, all data): pos RMS {reg_stats['pos_rms_um']:.1f} um per component, "
          f"rot RMS {reg_stats['rot_rms_urad']:.1f} urad per component")
    for name, r in ref.items():
        print(f"{name}: fit-all pos {r['fit_all_on_all']['pos_rms_um']:.1f} um rot {r['fit_all_on_all']['rot_rms_urad']:.1f} urad | "
              f"A->B pos {r['fit_A_predict_B']['pos_rms_um']:.1f} (|d| rms {r['fit_A_predict_B']['pos_norm_rms_um']:.1f}, mean {r['fit_A_predict_B']['pos_norm_mean_um']:.1f}) "
              f"B->A pos {r['fit_B_predict_A']['pos_rms_um']:.1f} (|d| rms {r['fit_B_predict_A']['pos_norm_rms_um']:.1f}, mean {r['fit_B_predict_A']['pos_norm_mean_um']:.1f}) "
              f"rot A->B {r['fit_A_predict_B']['rot_rms_urad']:.1f} B->A {r['fit_B_predict_A']['rot_rms_urad']:.1f}")


if __name__ == "__main__":
    main()
