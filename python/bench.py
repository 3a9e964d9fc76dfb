"""Benchmarks of the Python package (figures, not tests; run with the wheel installed):

1. poses/s of `Model.eval` called from Python (into a preallocated `out`) against the Rust API's
   own batch call (`Model::eval_rows`) in the same binary, on the same states;
2. the same evaluation split over 1, 2 and 4 Python threads (the GIL is released).

    python python/bench.py [--poses 200000] [--repeats 20]
"""

import argparse
import os
import threading
import time
from pathlib import Path

import numpy as np

import kin

ROOT = Path(__file__).resolve().parents[1]


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--model", default=str(ROOT / "examples" / "robot_6axis.kin"))
    p.add_argument("--poses", type=int, default=200_000)
    p.add_argument("--repeats", type=int, default=20)
    a = p.parse_args()
    m = kin.Model.from_file(a.model)
    rng = np.random.default_rng(0)
    q = np.ascontiguousarray(rng.uniform(-0.5, 0.5, (a.poses, len(m.axes))))
    t = np.zeros((a.poses, len(m.inputs)))
    out = np.empty((a.poses, 6))
    m.eval(q, inputs=t, out=out)
    t0 = time.perf_counter()
    for _ in range(a.repeats):
        m.eval(q, inputs=t, out=out)
    py_s = (time.perf_counter() - t0) / a.repeats
    rust_s = kin._kin._rust_eval_seconds(m, q, a.repeats)
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(f"{m.name}: {len(m.coefficients)} coefficients, {a.poses} poses")
    print(f"Rust API (eval_rows): {a.poses / rust_s:12,.0f} poses/s")
    print(f"Python   (eval, out=): {a.poses / py_s:12,.0f} poses/s  = {rust_s / py_s:.3f} × Rust")
    base = None
    for threads in (1, 2, 4):
        parts = np.array_split(np.arange(a.poses), threads)
        qs = [np.ascontiguousarray(q[i]) for i in parts]
        ts = [np.ascontiguousarray(t[i]) for i in parts]
        outs = [np.empty((len(i), 6)) for i in parts]
        t0 = time.perf_counter()
        for _ in range(a.repeats):
            ths = [threading.Thread(target=m.eval, args=(x,), kwargs={"inputs": ti, "out": o})
                   for x, ti, o in zip(qs, ts, outs)]
            for th in ths:
                th.start()
            for th in ths:
                th.join()
        s = (time.perf_counter() - t0) / a.repeats
        base = base or s
        print(f"{threads} thread(s): {a.poses / s:12,.0f} poses/s  = {base / s:.2f} × one thread")


if __name__ == "__main__":
    main()
