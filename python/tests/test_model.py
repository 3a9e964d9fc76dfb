import json
import pickle
import subprocess
import threading
import tracemalloc

import numpy as np
import pytest

import kin
from conftest import EXAMPLES

SLIDE = """machine slide {
    task position
    axis X prismatic along x range 0 mm .. 500 mm
    tool chain { X moving tool t at (0, 0, -100) mm }
    errors { X.tx = spline(X, knots 2)  X.ry = const }
}
params { X.tx = [2, -1, 0.5, 0.2] um  X.ry[0] = 3 urad }"""


XY = """machine xy {
    task position
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 400 mm
    tool chain { X moving Y moving tool t at (0, 0, -100) mm }
    errors { X.tx = spline(X, knots 2)  Y.ty = linear(Y)  X.rz = const }
}
params { X.tx = [2, -1, 0.5, 0.2] um  Y.ty[0] = 3 um  X.rz[0] = 5 urad }"""


def states_of(model, n, seed=1):
    """Random joint positions inside a model's declared ranges (SI)."""
    rng = np.random.default_rng(seed)
    return np.ascontiguousarray(rng.uniform(0.0, 0.4, (n, len(model.axes))))


def test_compile_errors_are_located_exceptions():
    bad = "machine m {\n    task position\n    axis X wobbly along x\n}"
    with pytest.raises(kin.CompileError) as e:
        kin.Model.compile(bad)
    err = e.value
    assert isinstance(err, kin.KinError)
    assert err.code.startswith("E")
    assert err.line == 3
    assert err.column >= 1
    assert err.diagnostics and err.diagnostics[0]["line"] == 3
    assert err.message in str(err)


def test_params_errors_are_located_in_the_params_text():
    m = kin.Model.compile(SLIDE)
    with pytest.raises(kin.CompileError) as e:
        m.with_params("params {\n  X.nope = 3 um\n}")
    assert e.value.line == 2


def test_a_model_file_that_does_not_compile_names_its_file(tmp_path):
    p = tmp_path / "bad.kin"
    p.write_text("machine m { axis X wobbly }")
    with pytest.raises(kin.CompileError) as e:
        kin.Model.from_file(str(p))
    assert e.value.path == str(p)


def test_the_error_is_linear_in_beta_with_the_jacobian():
    # err(β₂) − err(β₁) = J (β₂ − β₁): the first-order model is linear in β (thesis eq. 3.1).
    m = kin.Model.compile(CMM)
    q = states_of(m, 50)
    t = np.full((50, len(m.inputs)), 2.0)
    rng = np.random.default_rng(3)
    b1 = rng.normal(0, 1e-6, len(m.coefficients))
    b2 = rng.normal(0, 1e-6, len(m.coefficients))
    e1, j1 = m.with_beta(b1).eval_jacobian(q, inputs=t)
    e2 = m.with_beta(b2).eval(q, inputs=t)
    pred = e1 + np.einsum("ncj,j->nc", j1, b2 - b1)
    assert np.allclose(pred, e2, rtol=0, atol=1e-12 * np.abs(e2).max())


def test_position_rows_are_the_full_jacobians_first_three():
    m = kin.Model.compile(CMM)
    q = states_of(m, 20)
    t = np.full((20, len(m.inputs)), 2.0)
    e, j = m.eval_jacobian(q, inputs=t)
    ep, jp = m.eval_jacobian(q, inputs=t, observe="position")
    assert ep.shape == (20, 3) and jp.shape == (20, 3, len(m.coefficients))
    assert np.array_equal(ep, e[:, :3]) and np.array_equal(jp, j[:, :3, :])
    with pytest.raises(kin.KinError):
        m.eval_jacobian(q, inputs=t, observe="orientation")


# A measuring machine with a rotary table, an input and several term families, its β bound
# by its own params block: the reference for comparing with the command line.
CMM = """machine probe_cmm {
    task measure
    units { length mm, angle deg, error um, tilt urad, temperature degC }
    axis Y prismatic along y range 0 mm .. 500 mm
    axis X prismatic along x range 0 mm .. 400 mm
    axis C revolute about z continuous
    input T : temperature rise range 0 degC .. 10 degC
    tool chain { Y moving  X moving at (0, 0, 300) mm  tool probe at (0, 0, -100) mm }
    workpiece chain { C moving at (200, 250, -200) mm  workpiece }
    errors {
        Y.ty = spline(Y, knots 3) + linear(T) * linear(Y)
        X.tx = spline(X, knots 2)
        Y.rz = const
        C.tx = fourier(C, harmonics 1..2)
    }
}
params { Y.ty[0] = 1.5 um  Y.ty[2] = -0.7 um  X.tx[1] = -2 um  Y.rz[0] = 12 urad  C.tx[0] = 3 um  C.tx[1] = -1 um }
"""


def test_eval_equals_the_rust_cli(tmp_path, kin_bin):
    # `kin eval` (the Rust API behind the command line) writes its predictions to a CSV in the
    # model's display units; the Python package must give the same numbers to 1e-12.
    src = tmp_path / "cmm.kin"
    src.write_text(CMM)
    m = kin.Model.from_file(str(src))
    poses = tmp_path / "poses.csv"
    kin.simulate(m, poses, 300, seed=5)
    out = tmp_path / "pred.csv"
    subprocess.run([kin_bin, "eval", str(src), str(poses), "-o", str(out)],
                   check=True, capture_output=True)
    df = kin.read_measurements(m, poses)
    pred = kin.read_measurements(m, out, poses=True)
    q = np.column_stack([df["Y[mm]"] * 1e-3, df["X[mm]"] * 1e-3, np.radians(df["C[deg]"])])
    t = df[["T[degC]"]].to_numpy()  # a rise: kelvin = degrees Celsius
    ours = m.eval(np.ascontiguousarray(q), inputs=np.ascontiguousarray(t))
    assert np.abs(ours[:, :3]).max() > 1e-6  # the comparison is of real errors
    for c, name in enumerate(["ex", "ey", "ez"]):
        theirs = pred[f"{name}[um]"].to_numpy() * 1e-6
        assert np.allclose(ours[:, c], theirs, rtol=1e-12, atol=1e-12 * np.abs(theirs).max()), name


def test_evaluation_writes_into_out_without_allocating():
    m = kin.Model.compile(SLIDE)
    n = 200_000
    q = states_of(m, n)
    out = np.empty((n, 6))
    jac = np.empty((n, 6, len(m.coefficients)))
    e_out = np.empty((n, 6))
    m.eval(q, out=out)  # warm-up
    tracemalloc.start()
    r = m.eval(q, out=out)
    e, j = m.eval_jacobian(q, out=e_out, jac_out=jac)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert r is out and e is e_out and j is jac
    # One row's output alone would be 48 bytes × 200 000 = 9.6 MB: nothing near that.
    assert peak < 64 * 1024, peak
    # Without `out` the result is one new array of exactly N × 6 values.
    tracemalloc.start()
    fresh = m.eval(q)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < fresh.nbytes + 64 * 1024
    assert np.array_equal(fresh, out)


def test_bad_arrays_are_refused_with_a_clear_error():
    m = kin.Model.compile(SLIDE)
    q = np.zeros((10, 2))
    with pytest.raises(kin.EvalError, match=r"\(N, 1\)"):
        m.eval(q)
    with pytest.raises(kin.EvalError, match="2-dimensional"):
        m.eval(np.zeros(10))
    with pytest.raises(ValueError):
        m.eval([["a"], ["b"]])
    with pytest.raises(kin.EvalError, match="shape"):
        m.eval(np.zeros((10, 1)), out=np.empty((9, 6)))
    q = np.full((5, 1), 0.1)
    q[3, 0] = np.nan
    with pytest.raises(kin.EvalError) as e:
        m.eval(q)
    assert e.value.row == 3


def test_a_result_that_overflows_is_an_error_naming_its_row():
    # A finite but absurd position: the spline's values overflow. An infinity must not come
    # back as a number, from the error or from its Jacobian.
    m = kin.Model.compile(SLIDE)
    q = np.full((5, 1), 0.1)
    q[2, 0] = 1e300
    for call in (m.eval, m.eval_jacobian):
        with pytest.raises(kin.EvalError, match="too large for double precision") as e:
            call(q)
        assert e.value.row == 2
    err, jac = m.eval_jacobian(q[:2])
    assert np.isfinite(err).all() and np.isfinite(jac).all()


def test_every_array_a_numpy_user_passes_gives_the_same_numbers():
    # `DataFrame.to_numpy()` gives a Fortran-ordered array: its memory is column after column,
    # which read as rows would mix the axes' values. It, a strided view, a list, integers and
    # float32 are all read as the float64 rows they mean.
    m = kin.Model.compile(XY)
    q = states_of(m, 7)
    want = m.eval(q)
    want_err, want_jac = m.eval_jacobian(q)
    wide = np.zeros((7, 4))
    wide[:, ::2] = q
    for given in (
        np.asfortranarray(q),
        wide[:, ::2],
        q.tolist(),
    ):
        assert np.array_equal(m.eval(given), want)
        err, jac = m.eval_jacobian(given)
        assert np.array_equal(err, want_err) and np.array_equal(jac, want_jac)
    # float32 and integers: converted, not refused (the values they hold).
    single = q.astype(np.float32)
    assert np.array_equal(m.eval(single), m.eval(single.astype(np.float64)))
    ints = np.array([[1, 0], [0, 1]], dtype=np.int64)
    assert np.array_equal(m.eval(ints), m.eval(ints.astype(np.float64)))
    # A C-contiguous float64 array is read in place: the same object, no copy.
    assert np.shares_memory(np.asarray(q), q)


def test_joint_jacobian_of_a_slide_is_its_axis():
    m = kin.Model.compile(SLIDE)
    j = m.joint_jacobian(np.array([[0.1], [0.3]]))
    assert j.shape == (2, 1, 6)
    assert np.allclose(j[:, 0, :], [1, 0, 0, 0, 0, 0])


def test_compensation_cancels_the_error_of_a_positioning_machine():
    m = kin.Model.compile("""machine xy {
        task position
        axis X prismatic along x range 0 mm .. 500 mm
        axis Y prismatic along y range 0 mm .. 500 mm
        tool chain { X moving Y moving tool t }
        errors { X.tx = spline(X, knots 3)  Y.ty = spline(Y, knots 2) }
    }""")
    m = m.with_beta(np.random.default_rng(4).normal(0, 5e-6, len(m.coefficients)))
    q = np.array([[0.1, 0.2], [0.4, 0.3], [0.25, 0.05]])
    dq = m.compensate(q, position_only=True)
    err = m.eval(q)
    # Each axis moves against its own positioning error (to first order: the error changes
    # by its slope × the correction, ~1e-5 of it, at the corrected pose).
    assert np.allclose(dq, -err[:, :2], rtol=1e-3, atol=1e-12)
    with pytest.raises(kin.KinError):
        kin.Model.compile(CMM).compensate(np.zeros((1, 3)))


def test_compensation_moves_the_axes_it_is_given():
    # A rotary table under a position-only correction is held (as `kin compensate --correct
    # position` holds it) unless `axes` names it; an unknown name is an error.
    m = kin.Model.compile("""machine xc {
        task position
        axis X prismatic along x range 0 mm .. 500 mm
        axis Y prismatic along y range 0 mm .. 500 mm
        axis C revolute about z continuous
        tool chain { X moving Y moving tool t }
        workpiece chain { C fixed at (0, 0, 50) mm  workpiece }
        errors { X.tx = linear(X)  C.tx = const  C.rz = const }
    }""")
    m = m.with_beta(np.array([20e-6, 10e-6, 30e-6]))
    q = np.array([[0.1, 0.2, 0.3], [0.4, 0.3, 1.0]])
    held = m.compensate(q, position_only=True)
    assert np.all(held[:, 2] == 0.0) and np.abs(held[:, :2]).max() > 1e-6
    free = m.compensate(q, position_only=True, axes=["X", "Y", "C"])
    assert np.abs(free[:, 2]).max() > 0.0
    only_x = m.compensate(q, position_only=True, axes=["X"])
    assert np.all(only_x[:, 1:] == 0.0)
    with pytest.raises(kin.KinError):
        m.compensate(q, axes=["W"])


def test_models_pickle_and_save_bit_for_bit(tmp_path):
    m = kin.Model.compile(SLIDE)
    q = states_of(m, 20)
    back = pickle.loads(pickle.dumps(m))
    assert np.array_equal(back.eval(q), m.eval(q))
    m.save(str(tmp_path / "m.json"))
    assert np.array_equal(kin.Model.load(str(tmp_path / "m.json")).eval(q), m.eval(q))


def test_threads_evaluate_one_model_at_once():
    # Correctness from several threads (the speed-up is a benchmark: python/bench.py).
    m = kin.Model.compile(CMM)
    q = states_of(m, 20_000)
    t = np.zeros((len(q), len(m.inputs)))
    want = m.eval(q, inputs=t)
    outs = [np.empty_like(want) for _ in range(4)]
    ths = [threading.Thread(target=m.eval, args=(q,), kwargs={"inputs": t, "out": o}) for o in outs]
    for th in ths:
        th.start()
    for th in ths:
        th.join()
    for o in outs:
        assert np.array_equal(o, want)


def test_a_large_batch_is_each_state_on_its_own():
    # The batch goes to the model in blocks of states (the error alone two states a call): every
    # row is what the state alone gives, bit for bit, across the blocks' edges, for the errors,
    # the full Jacobian and the position rows; a bad state past the first block is named by its
    # own row.
    m = kin.Model.compile(XY)
    q = states_of(m, 2500, seed=4)
    err = m.eval(q)
    jerr, jac = m.eval_jacobian(q)
    perr, pjac = m.eval_jacobian(q, observe="position")
    for i in (0, 1, 1023, 1024, 1025, 2047, 2048, 2499):
        one = q[i : i + 1]
        assert np.array_equal(err[i], m.eval(one)[0]), i
        e1, j1 = m.eval_jacobian(one)
        assert np.array_equal(jerr[i], e1[0]) and np.array_equal(jac[i], j1[0]), i
        p1, pj1 = m.eval_jacobian(one, observe="position")
        assert np.array_equal(perr[i], p1[0]) and np.array_equal(pjac[i], pj1[0]), i
        assert np.array_equal(pjac[i], jac[i, :3]), i
    q[2100, 1] = np.nan
    for call in (m.eval, m.eval_jacobian):
        with pytest.raises(kin.EvalError) as e:
            call(q)
        assert e.value.row == 2100
