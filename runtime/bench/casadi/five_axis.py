"""The 5-axis example (`examples/milling_5axis.kin`) written as a CasADi user writes it, for the
comparison of kin's generated code with CasADi's (issue 36; `runtime/bench/benches/casadi.rs`).

A CasADi user writes the tool-location error as a symbolic expression of the pose and of the
coefficients β and asks CasADi for its Jacobian with respect to β and for C code of both. This
file does that for the same machine and the same first-order model kin compiles: the closed-form
kinematics of the table-table mill, the F-matrix columns (thesis eq. 2.27/2.28) and every error
term's basis functions, written after the hand-written evaluator
(`runtime/bench/src/baseline_5axis.rs`), whose tables (knots, trends, periodic α, offsets,
scalings) it reads from the JSON `five_axis_tables` prints, so that nothing is worked out twice.
The sines and cosines are written the plain way, `sin(h·c)` and `cos(h·c)` for harmonic h.

Usage: python five_axis.py TABLES.json OUT.c

The same model is written three ways, each a prefix of four functions:
  kin5   the closed form above;
  kin5c  the chain of homogeneous transforms with each element's error transform, its
         derivative with respect to the errors at zero (the F-matrices) left to CasADi, the
         workpiece chain inverted as a rigid transform;
  kin5g  the same with CasADi's general 4 x 4 inverse `inv`, as one might first write it.

Writes OUT.c with, for each prefix P, the functions `f(arg, res, iw, w, mem)` of CasADi's C API:
  P_ej   (q, dirs, inputs, lags, tool, probe, beta) -> (e[6], J 6 x n, CasADi's sparse form)
  P_ejd  the same with J dense, stored row by row (the layout kin writes)
  P_ejp  the position rows only: e[3], J 3 x n dense row by row
  P_e    the error alone, e[6]
with `tool` the tool's offset (3) and `probe` 1 for the probe, 0 for the spindle.
"""

import json
import math
import sys

import casadi as ca


def main(tables_path, out_path):
    with open(tables_path) as f:
        tb = json.load(f)
    n = tb["coefficients"]

    q = ca.SX.sym("q", 5)
    dirs = ca.SX.sym("dirs", 5)
    inputs = ca.SX.sym("inputs", 3)
    lags = ca.SX.sym("lags", 2)
    tool = ca.SX.sym("tool", 3)
    probe = ca.SX.sym("probe", 1)
    beta = ca.SX.sym("beta", n)
    y, x, z, a, c = q[0], q[1], q[2], q[3], q[4]

    def scalar(s):
        """A scaling or fixed term of the model (kin's `Scalar`, as serde writes it)."""
        (kind, v), = s.items()
        if kind == "Num":
            return v
        if kind == "Var":
            (var, i), = v.items()
            return {"Axis": q, "Input": inputs, "Lag": lags, "Direction": dirs}[var][i]
        if kind == "Neg":
            return -scalar(v)
        if kind == "Sin":
            return ca.sin(scalar(v))
        if kind == "Cos":
            return ca.cos(scalar(v))
        l, r = scalar(v[0]), scalar(v[1])
        return {"Add": l + r, "Sub": l - r, "Mul": l * r, "Div": l / r}[kind]

    def tp2(u, t):
        d = ca.fmax(u - t, 0)
        return d * d

    def s_of(qd, x):
        return (x - qd["lo"]) / qd["span"]

    def plain(qd, x):
        """A quadratic spline's functions s, s², (s − t_k)₊² (eq. 3.2–3.3)."""
        s = s_of(qd, x)
        return [s, s * s] + [tp2(s, k) for k in qd["knots"]]

    def straight(qd, x):
        """Straightness: s², (s − t_k)₊², each less its trend line (eq. 3.4–3.8)."""
        s = s_of(qd, x)
        t = qd["trend"]
        out = [s * s - (t[0][0] + t[0][1] * s)]
        for k, knot in enumerate(qd["knots"]):
            out.append(tp2(s, knot) - (t[1 + k][0] + t[1 + k][1] * s))
        return out

    def no_rev(qd, x, cos, sin):
        """A spline less its once-per-revolution part (eq. 3.9)."""
        g = plain(qd, x)
        t = qd["trend"]
        return [g[k] - t[k][0] * cos - t[k][1] * sin for k in range(len(g))]

    def periodic(pd, x):
        """Periodic terms v(w) = (w − t)₊² − w·(α1 + w·α2) (eq. 3.12–3.13)."""
        yy = x / pd["tau"]
        w = yy - ca.floor(yy)
        w = ca.if_else(w >= 1, 0, w)
        return [
            tp2(w, knot) - (al[1] * w + al[0]) * w
            for knot, al in zip(pd["knots"], pd["alpha"])
        ]

    # ---- Kinematics: fixed frames before their joints (eq. 2.35–2.38).
    sa, cs_a = ca.sin(a), ca.cos(a)
    sc, cc = ca.sin(c), ca.cos(c)
    s_y, s_x, s_a, s_c, s_z = (tb[k] for k in ("s_y", "s_x", "s_a", "s_c", "s_z"))
    p_y = s_y
    p_x = [p_y[0] + s_x[0], p_y[1] - y + s_x[1], p_y[2] + s_x[2]]
    p_a = [p_x[0] - x + s_a[0], p_x[1] + s_a[1], p_x[2] + s_a[2]]
    p_c = [
        p_a[0] + s_c[0],
        p_a[1] + (cs_a * s_c[1] - sa * s_c[2]),
        p_a[2] + (sa * s_c[1] + cs_a * s_c[2]),
    ]
    # M = R(wr→base)ᵀ = (R_x(a)·R_z(c))ᵀ, by rows.
    m = [[cc, cs_a * sc, sa * sc], [-sc, cs_a * cc, sa * cc], [0, -sa, cs_a]]
    p_z = [s_z[0], s_z[1], s_z[2] + z]
    p_t = [p_z[0] + tool[0], p_z[1] + tool[1], p_z[2] + tool[2]]

    def arm(p):
        d = [p_t[i] - p[i] for i in range(3)]
        return [m[i][0] * d[0] + m[i][1] * d[1] + m[i][2] * d[2] for i in range(3)]

    def rcol(r, ar):
        return [
            r[1] * ar[2] - r[2] * ar[1],
            r[2] * ar[0] - r[0] * ar[2],
            r[0] * ar[1] - r[1] * ar[0],
            r[0],
            r[1],
            r[2],
        ]

    mc = [[m[0][j], m[1][j], m[2][j]] for j in range(3)]
    nm = [[-v for v in col] for col in mc]
    nrc = [[-cc, sc, 0], [-sc, -cc, 0], [0, 0, -1]]

    # ---- C's basis factors take its angle reduced to one turn.
    tau = 2 * math.pi
    r = ca.fmod(c, tau)
    xc = ca.if_else(r < 0, r + tau, r)

    def h(k):
        return ca.cos(k * xc), ca.sin(k * xc)

    (c1, s1), (c2, s2), (c3, s3), (c4, s4) = h(1), h(2), h(3), h(4)
    (c90, s90), (c180, s180) = h(90), h(180)
    rev_c, rev_s = ca.cos(xc - tb["c_mid"]), ca.sin(xc - tb["c_mid"])

    # Every error term: (element, component, first coefficient, basis values, fixed part).
    # Components 0–5 are tx, ty, tz, rx, ry, rz; "tool" is the tool frame of every tool,
    # "probe" the probe's alone (its terms count for the probe only: `probe` is 0 or 1).
    terms = []

    def term(frame, comp, j0, values, fixed=0):
        terms.append((frame, comp, j0, values, fixed))

    TX, TY, TZ, RX, RY, RZ = range(6)
    # ---- Y saddle.
    term("Y", TY, 0, plain(tb["y_ty"], y) + periodic(tb["y_per"], y) + [dirs[0]],
         scalar(tb["y_scale"]))
    st = straight(tb["y_str"], y)
    term("Y", TX, 9, st)
    term("Y", TZ, 13, st)
    rot = plain(tb["y_rot"], y)
    load = scalar(tb["y_load"])
    term("Y", RX, 17, rot + [load * v for v in plain(tb["x_load"], x)])
    term("Y", RY, 26, rot)
    term("Y", RZ, 31, rot)
    # ---- X table.
    term("X", TX, 36, plain(tb["x_tx"], x) + periodic(tb["x_per"], x) + [dirs[1]])
    st = straight(tb["x_str"], x)
    term("X", TY, 46, st)
    term("X", TZ, 51, st)
    rot = plain(tb["x_rot"], x)
    term("X", RX, 56, rot)
    term("X", RY, 61, rot)
    term("X", RZ, 66, rot + [1])
    # ---- Z headstock.
    zt = tb["z_tz"]
    s = (z - zt["lo"]) / zt["span"]
    term("Z", TZ, 72, [s, s * s, s * s * s] + [ca.fmax(s - k, 0) ** 3 for k in zt["knots"]])
    st = straight(tb["z_str"], z)
    term("Z", TX, 79, st)
    term("Z", TY, 83, st)
    rot = plain(tb["z_rot"], z)
    term("Z", RX, 87, rot + [1])
    term("Z", RY, 92, rot + [1])
    term("Z", RZ, 97, rot)
    # ---- A trunnion: Legendre polynomials on [−1, 1].
    u = 2 * ((a - tb["a_lo"]) / tb["a_span"]) - 1
    p2 = (3 * u * u - 1) / 2
    p3 = (5 * u * p2 - 2 * u) / 3
    term("A", TX, 101, [u, p2, p3])
    sp = [1] + plain(tb["a_sp2"], a)
    term("A", TY, 104, sp)
    term("A", TZ, 109, sp)
    term("A", RY, 114, [1, u])
    term("A", RZ, 116, [1, u])
    term("A", RX, 118, plain(tb["a_sp3"], a) + [dirs[3]])
    # ---- C rotary table.
    term("C", TX, 124, [1, c2, s2, c3, s3, c4, s4])
    term("C", TY, 131, [1] + no_rev(tb["c_rev"], xc, rev_c, rev_s))
    term("C", TZ, 140, [c1, s1, c2, s2, c3, s3])
    term("C", RX, 146, [1, c2, s2, c3, s3])
    term("C", RY, 151, [1, c2, s2, c3, s3])
    term("C", RZ, 156, [c1, s1, c2, s2, c3, s3, c4, s4, c90, s90, c180, s180])
    # ---- Tools: thermal growth of every tool, offsets of the probe.
    term("tool", TZ, 168, [lags[0]])
    term("tool", RY, 169, [lags[1]])
    for k in range(3):
        term("probe", k, 170 + k, [probe])

    def value(values, j0, fixed):
        out = fixed
        for k, v in enumerate(values):
            out = out + v * beta[j0 + k]
        return out

    # ---- The closed form: each term's column of the F-matrix (eq. 2.27/2.28) in wr axes,
    # written out for this machine as the hand-written evaluator writes it.
    ay, ax, az, aa, ac = arm(p_y), arm(p_x), arm(p_z), arm(p_a), arm(p_c)
    rotation = {"Y": nm, "X": nm, "A": nm, "C": nrc, "Z": mc, "tool": mc, "probe": mc}
    lever = {"Y": ay, "X": ax, "A": aa, "C": ac, "Z": az, "tool": [0, 0, 0]}
    e = [0] * 6
    for frame, comp, j0, values, fixed in terms:
        r = rotation[frame][comp % 3]
        col = r if comp < 3 else rcol(r, lever[frame])
        v = value(values, j0, fixed)
        for i, ci in enumerate(col):
            e[i] = e[i] + ci * v

    err = ca.vertcat(*e)

    # ---- The chain: the same first-order model as a CasADi user gets it without working out the
    # F-matrices, from the machine's homogeneous transforms (spec/kinematics.md): each element's
    # six parametric errors ε as symbols, the tool's location in the workpiece frame with every
    # error transform in place, its derivative with respect to ε at ε = 0 (eq. 2.24) left to
    # CasADi, and the error that derivative times each component's sum of terms.
    eps = {f: ca.SX.sym("eps_" + f, 6) for f in ("Y", "X", "A", "C", "Z", "tool", "probe")}

    def translation(v):
        t = ca.SX.eye(4)
        for i in range(3):
            t[i, 3] = v[i]
        return t

    def rotation_about(axis, angle):
        t = ca.SX.eye(4)
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        cs, sn = ca.cos(angle), ca.sin(angle)
        t[i, i], t[i, j], t[j, i], t[j, j] = cs, -sn, sn, cs
        return t

    def error(f):
        """Trans(tx, ty, tz) · Rot_x(rx) · Rot_y(ry) · Rot_z(rz) (eq. 2.8)."""
        d = eps[f]
        return ca.mtimes([translation(d[:3]), rotation_about(0, d[3]),
                          rotation_about(1, d[4]), rotation_about(2, d[5])])

    # Workpiece chain: every frame fixed, so T(k−1 → k) = J_{k−1} · S_k (the first one S_Y).
    to_wr = ca.mtimes([
        translation(s_y), error("Y"), translation([0, -y, 0]),
        translation(s_x), error("X"), translation([-x, 0, 0]),
        translation(s_a), error("A"), rotation_about(0, a),
        translation(s_c), error("C"), rotation_about(2, c),
    ])
    # Tool chain: Z moving, then the tool's offset and its errors (the probe's only for it).
    tool_error = ca.mtimes(error("tool"), translation(probe * eps["probe"][:3]))
    to_tl = ca.mtimes([translation(s_z), translation([0, 0, z]), error("Z"),
                       translation(tool), tool_error])

    def chain(rigid):
        """The error through T(wr → tl) = T(0 → wr)⁻¹·T(0 → tl): with `rigid`, the inverse
        of a rigid transform (Rᵀ, −Rᵀ·p); without, CasADi's general `inv` of the 4 × 4 matrix,
        which divides by the determinant and hides the chain's structural zeros from CasADi."""
        if rigid:
            inv_wr = ca.SX.eye(4)
            inv_wr[:3, :3] = to_wr[:3, :3].T
            inv_wr[:3, 3] = -ca.mtimes(to_wr[:3, :3].T, to_wr[:3, 3])
        else:
            inv_wr = ca.inv(to_wr)
        rel = ca.mtimes(inv_wr, to_tl)
        zero = {f: ca.DM.zeros(6) for f in eps}
        names_eps = list(eps)
        at_zero = lambda expr: ca.substitute([expr], [eps[f] for f in names_eps],
                                             [zero[f] for f in names_eps])[0]
        nominal = at_zero(rel)
        position = rel[:3, 3] - nominal[:3, 3]
        # R_actual ≈ (I + [r]×)·R_nominal: r from the skew part of R_actual·R_nominalᵀ.
        w = ca.mtimes(rel[:3, :3], nominal[:3, :3].T)
        spin = 0.5 * ca.vertcat(w[2, 1] - w[1, 2], w[0, 2] - w[2, 0], w[1, 0] - w[0, 1])
        exact = ca.vertcat(position, spin)
        all_eps = ca.vertcat(*[eps[f] for f in names_eps])
        g = at_zero(ca.jacobian(exact, all_eps))
        sums = {f: [0] * 6 for f in names_eps}
        for frame, comp, j0, values, fixed in terms:
            sums[frame][comp] = sums[frame][comp] + value(values, j0, fixed)
        return ca.mtimes(g, ca.vertcat(*[v for f in names_eps for v in sums[f]]))

    args = [q, dirs, inputs, lags, tool, probe, beta]
    names = ["q", "dirs", "inputs", "lags", "tool", "probe", "beta"]
    # Row by row: the transpose's dense column-major storage is the matrix's row-major one.
    rows = lambda j: ca.densify(j.T)
    functions = []
    models = [("kin5", err), ("kin5c", chain(True)), ("kin5g", chain(False))]
    for prefix, e_ in models:
        j_ = ca.jacobian(e_, beta)
        functions += [
            ca.Function(prefix + "_ej", args, [e_, j_], names, ["e", "J"]),
            ca.Function(prefix + "_ejd", args, [e_, rows(j_)], names, ["e", "J"]),
            ca.Function(prefix + "_ejp", args, [e_[:3], rows(j_[:3, :])], names, ["e", "J"]),
            ca.Function(prefix + "_e", args, [e_], names, ["e"]),
        ]
    gen = ca.CodeGenerator(out_path, {"casadi_real": "double", "casadi_int": "long long"})
    for f in functions:
        gen.add(f)
    gen.generate()
    print(
        f"{out_path}: CasADi {ca.__version__}, {n} coefficients, "
        "Jacobian's structural non-zeros of "
        f"{6 * n}: " + ", ".join(f"{p} {ca.jacobian(e_, beta).nnz()}" for p, e_ in models),
        file=sys.stderr,
    )


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python five_axis.py TABLES.json OUT.c")
    main(sys.argv[1], sys.argv[2])
