"""A large data set, never loaded whole: thermal logs in Parquet, fitted in row batches.

A slide's positioning error grows with its temperature rise (`X.tx` has a thermal term). Rows
of (X, Z, T, ex) are generated, written to a Parquet file in row groups with pyarrow, then read
back a batch at a time through Arrow and streamed into `kin.StreamingFit`: memory is one batch
and the (coefficients + 1)² triangle. Partitions of the file are fitted separately, as workers
of a cluster would, and their triangles merged (TSQR) give the same β as one stream.

`python examples/python/thermal_parquet.py --rows 10000000` is the full-size run (its peak
memory is printed); the tests run it smaller.
"""

# %% Setup
from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path
from typing import List

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

import kin

MODEL = """machine thermal_slide {
    task position
    units { length mm, error um, temperature degC }
    axis X prismatic along x range 0 mm .. 1000 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    input T : temperature rise range 0 degC .. 10 degC
    tool chain { X moving  Z moving  tool spindle at (0, 0, -100) mm }
    errors {
        X.tx = spline(X, knots 4) + linear(X) * linear(T)
        X.ry = spline(X, knots 3)
        Z.tz = spline(Z, knots 2) + linear(T)
    }
}
"""


# %% Generate the logs
def generate(path: Path, rows: int, batch: int = 1_000_000, seed: int = 7) -> np.ndarray:
    """Writes `rows` rows to `path` (Parquet, one row group per batch); returns the truth β."""
    model = kin.Model.compile(MODEL)
    rng = np.random.default_rng(seed)
    truth = rng.normal(0.0, 2e-6, len(model.coefficients))
    model = model.with_beta(truth)
    schema = pa.schema([("X", pa.float64()), ("Z", pa.float64()), ("T", pa.float64()),
                        ("ex", pa.float64()), ("ez", pa.float64())])
    with pq.ParquetWriter(path, schema) as w:
        done = 0
        while done < rows:
            n = min(batch, rows - done)
            q = np.column_stack([rng.uniform(0, 1.0, n), rng.uniform(-0.3, 0, n)])
            t = rng.uniform(0, 8.0, (n, 1))  # K of rise over a day
            err = model.eval(q, inputs=t)
            noise = rng.normal(0, 0.2e-6, (n, 2))
            w.write_table(pa.table({"X": q[:, 0], "Z": q[:, 1], "T": t[:, 0],
                                    "ex": err[:, 0] + noise[:, 0],
                                    "ez": err[:, 2] + noise[:, 1]}, schema=schema))
            done += n
    return truth


# %% Stream a part of the file into a fit
def fit_part(path: Path, groups: List[int], batch_rows: int = 262_144) -> kin.StreamingFit:
    """One partition (these row groups) streamed through Arrow record batches."""
    model = kin.Model.compile(MODEL)
    fit = kin.StreamingFit(model, observe=["ex", "ez"])
    f = pq.ParquetFile(path)
    for b in f.iter_batches(batch_size=batch_rows, row_groups=groups):
        cols = [np.asarray(b.column(c)) for c in ("X", "Z", "T", "ex", "ez")]
        states = np.ascontiguousarray(np.column_stack(cols[:2]))
        fit.add_batch(states, np.ascontiguousarray(np.column_stack(cols[3:])),
                      inputs=np.ascontiguousarray(cols[2][:, None]))
    return fit


def fit_partitioned(path: Path, parts: int) -> kin.StreamingFit:
    """The file's row groups split into `parts` partitions, fitted apart and merged (TSQR)."""
    groups = list(range(pq.ParquetFile(path).num_row_groups))
    chunks = [groups[i::parts] for i in range(parts)]
    fits = [fit_part(path, c) for c in chunks if c]
    total = fits[0]
    for other in fits[1:]:
        total.merge(other)
    return total


# %% The same on a cluster: each worker fits its partition, the triangles travel back
def fit_on_dask(path: Path, parts: int, workers: int) -> kin.StreamingFit:
    """`parts` partitions fitted on a Dask LocalCluster of `workers` processes; each task returns
    its StreamingFit (pickled as the model and its triangle), and the triangles are merged here."""
    from dask.distributed import Client, LocalCluster

    groups = list(range(pq.ParquetFile(path).num_row_groups))
    chunks = [c for c in (groups[i::parts] for i in range(parts)) if c]
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        fits = client.gather(client.map(fit_part, [str(path)] * len(chunks), chunks, pure=False))
    total = fits[0]
    for other in fits[1:]:
        total.merge(other)
    return total


# %% Run
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, default=1_000_000)
    p.add_argument("--path", default="thermal_logs.parquet")
    p.add_argument("--fit-only", action="store_true",
                   help="fit an existing file (a separate process, so the peak memory is the fit's)")
    a = p.parse_args(argv)
    path = Path(a.path)
    if a.fit_only:
        truth = None
    else:
        truth = generate(path, a.rows, batch=min(1_000_000, max(1, a.rows // 8)))
    start = time.perf_counter()
    fit = fit_part(path, list(range(pq.ParquetFile(path).num_row_groups)))
    solved = fit.solve()
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    rows = pq.ParquetFile(path).metadata.num_rows
    print(f"{solved['rows']} observed values from {rows} rows in {seconds:.1f} s; "
          f"σ̂ = {solved['sigma'] * 1e6:.3f} µm; peak memory {peak:.0f} MiB")
    for i, (name, b, se) in enumerate(zip(solved["names"], solved["beta"], solved["se"])):
        t = "" if truth is None else f"   truth {truth[i] * 1e6:+9.4f}"
        print(f"  {name:10s} {b * 1e6:+9.4f} ± {se * 1e6:.4f} (×1e-6, SI){t}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
