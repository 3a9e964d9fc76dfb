import pickle

import numpy as np
import pytest

import kin
import thermal_parquet as tp


def relative(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


def test_four_merged_partitions_give_the_single_stream_beta(tmp_path):
    path = tmp_path / "logs.parquet"
    truth = tp.generate(path, 80_000, batch=10_000)
    one = tp.fit_part(path, list(range(8)), batch_rows=7_000)
    merged = tp.fit_partitioned(path, 4)
    a, b = one.solve(), merged.solve()
    assert a["rows"] == b["rows"] == 160_000
    assert relative(b["beta"], a["beta"]) < 1e-10
    assert abs(a["sigma"] - b["sigma"]) < 1e-10 * a["sigma"]
    # And the fit is right: the truth within 5 standard errors, σ̂ at the noise.
    assert np.all(np.abs(a["beta"] - truth) < 5 * a["se"])
    assert 0.18e-6 < a["sigma"] < 0.22e-6


def test_partitions_fitted_on_dask_workers_merge_to_the_single_stream_beta(tmp_path):
    import cloudpickle

    cloudpickle.register_pickle_by_value(tp)
    path = tmp_path / "logs.parquet"
    tp.generate(path, 40_000, batch=5_000)
    one = tp.fit_part(path, list(range(8))).solve()
    spread = tp.fit_on_dask(path, parts=4, workers=2).solve()
    assert spread["rows"] == one["rows"] == 80_000
    assert relative(spread["beta"], one["beta"]) < 1e-10


def test_r_factors_merge_as_the_qr_of_the_stacked_triangles():
    m = kin.Model.compile(tp.MODEL)
    rng = np.random.default_rng(1)
    parts = []
    for _ in range(2):
        f = kin.StreamingFit(m, observe=["ex"], block=50)
        q = np.column_stack([rng.uniform(0, 1, 400), rng.uniform(-0.3, 0, 400)])
        f.add_batch(q, rng.normal(0, 1e-6, (400, 1)), inputs=rng.uniform(0, 5, (400, 1)))
        parts.append(f)
    r1, r2 = parts[0].r_factor(), parts[1].r_factor()
    parts[0].merge(parts[1])
    r = parts[0].r_factor()
    # RᵀR of the merge is R₁ᵀR₁ + R₂ᵀR₂ (= [X y]ᵀ[X y] of all rows).
    assert np.allclose(r.T @ r, r1.T @ r1 + r2.T @ r2, rtol=1e-12, atol=1e-24)
    assert parts[0].rows == 800


def test_a_partial_fit_pickles_to_another_process():
    m = kin.Model.compile(tp.MODEL)
    rng = np.random.default_rng(2)
    f = kin.StreamingFit(m, observe=["ex", "ez"])
    q = np.column_stack([rng.uniform(0, 1, 300), rng.uniform(-0.3, 0, 300)])
    f.add_batch(q, rng.normal(0, 1e-6, (300, 2)), inputs=rng.uniform(0, 5, (300, 1)))
    g = pickle.loads(pickle.dumps(f))
    assert g.rows == f.rows
    assert np.array_equal(g.r_factor(), f.r_factor())


def test_a_rank_deficient_stream_is_a_fit_error():
    m = kin.Model.compile(tp.MODEL)
    f = kin.StreamingFit(m, observe=["ex"])
    q = np.tile([[0.5, -0.1]], (100, 1))  # one pose: nothing varies
    f.add_batch(q, np.zeros((100, 1)), inputs=np.ones((100, 1)))
    with pytest.raises(kin.FitError):
        f.solve()
