"""Every function that takes arrays gives, for each layout and type a numpy user passes — a
Fortran-ordered array (what `DataFrame.to_numpy()` returns), a strided view, a list, float32 —
the numbers the same values give as C-contiguous float64 arrays: to the bit where the values
are the same doubles, and float32 as the float64 values it holds."""

import numpy as np
import pytest

import kin

# An input, backlash (directions) and a rotary axis: every array argument but `time` changes
# the numbers (the batch calls evaluate no term of time: lags and warm-ups need a run); `time`
# is still converted and checked like the others.
MODEL = """machine table {
    task position
    units { length mm, angle deg, error um, tilt urad, time min, temperature degC }
    axis Y prismatic along y range 0 mm .. 400 mm
    axis X prismatic along x range 0 mm .. 500 mm
    axis C revolute about z continuous
    input T : temperature rise range 0 degC .. 10 degC
    tool chain { Y moving  X moving  tool t at (0, 0, -100) mm }
    workpiece chain { C fixed at (0, 0, 50) mm  workpiece }
    errors {
        X.tx = linear(X) + backlash(X)
        Y.rz = const
        C.tx = const
        X.tz = T / 1 K * const
    }
}
params {
    X.tx = [4, 1] um
    Y.rz = [20] urad
    C.tx = [6] um
    X.tz = [2] um
}
"""

N = 9


def layouts(a):
    """The same values as a numpy user may hand them over."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    wide = np.zeros((a.shape[0], 2 * a.shape[1]) if a.ndim == 2 else 2 * a.shape[0])
    if a.ndim == 2:
        wide[:, ::2] = a
        strided = wide[:, ::2]
    else:
        wide[::2] = a
        strided = wide[::2]
    return [
        ("fortran", np.asfortranarray(a)),
        ("strided", strided),
        ("list", a.tolist()),
    ]


@pytest.fixture(scope="module")
def case():
    m = kin.Model.compile(MODEL)
    rng = np.random.default_rng(7)
    q = np.column_stack([rng.uniform(0, 0.4, N), rng.uniform(0, 0.5, N), rng.uniform(-3, 3, N)])
    inputs = rng.uniform(0, 5, (N, 1))
    time = np.arange(N, dtype=float) * 60.0
    dirs = np.where(rng.uniform(size=(N, 3)) > 0.5, 1.0, -1.0)
    return m, q, inputs, time, dirs


def same(a, b):
    if isinstance(a, tuple):
        return all(same(x, y) for x, y in zip(a, b))
    return np.array_equal(np.asarray(a), np.asarray(b))


def calls(m):
    """Every array-taking call, as a function of (states, inputs, time, dirs)."""
    return {
        "eval": lambda q, i, t, d: m.eval(q, inputs=i, time=t, dirs=d),
        "eval_jacobian": lambda q, i, t, d: m.eval_jacobian(q, inputs=i, time=t, dirs=d),
        "eval_jacobian position": lambda q, i, t, d: m.eval_jacobian(
            q, inputs=i, time=t, dirs=d, observe="position"
        ),
        "joint_jacobian": lambda q, i, t, d: m.joint_jacobian(q),
        # Compensation takes no directions: a model without the backlash.
        "compensate": lambda q, i, t, d: kin.Model.compile(
            MODEL.replace(" + backlash(X)", "").replace("X.tx = [4, 1] um", "X.tx = [4] um")
        ).compensate(q, inputs=i, time=t),
        "with_beta": lambda q, i, t, d: m.with_beta(np.asarray(m.beta)[::-1].copy()).eval(
            q, inputs=i, time=t, dirs=d
        ),
    }


@pytest.mark.parametrize("name", list(calls(kin.Model.compile(MODEL)).keys()))
def test_every_array_argument_in_every_layout(case, name):
    m, q, inputs, time, dirs = case
    call = calls(m)[name]
    want = call(q, inputs, time, dirs)
    for argument in ("states", "inputs", "time", "dirs"):
        base = {"states": q, "inputs": inputs, "time": time, "dirs": dirs}
        for layout, given in layouts(base[argument]):
            args = dict(base, **{argument: given})
            got = call(args["states"], args["inputs"], args["time"], args["dirs"])
            assert same(got, want), f"{name}: {argument} as {layout}"
    # float32 holds other values: they are read as the doubles they are.
    single = q.astype(np.float32)
    assert same(call(single, inputs, time, dirs), call(single.astype(np.float64), inputs, time, dirs))


def test_beta_and_streaming_batches_in_every_layout(case):
    m, q, inputs, time, dirs = case
    beta = np.asarray(m.beta)
    want = m.with_beta(beta).eval(q, inputs=inputs, time=time, dirs=dirs)
    for layout, given in layouts(beta):
        assert same(m.with_beta(given).eval(q, inputs=inputs, time=time, dirs=dirs), want), layout
    # A streamed fit of the model's own errors: every layout gives the same triangle.
    # (A streamed fit observes positions unless told otherwise.)
    obs = np.ascontiguousarray(m.eval(q, inputs=inputs, time=time, dirs=dirs)[:, :3])
    reference = kin.StreamingFit(m)
    reference.add_batch(q, obs, inputs=inputs, time=time, dirs=dirs)
    for layout, given in layouts(obs):
        s = kin.StreamingFit(m)
        s.add_batch(q, given, inputs=inputs, time=time, dirs=dirs)
        assert np.array_equal(s.r_factor(), reference.r_factor()), layout
