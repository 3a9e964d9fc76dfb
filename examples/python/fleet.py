"""Calibrating a fleet of machines on Dask: one task per machine, one table at the end.

Run it as a script (`python examples/python/fleet.py --machines 50 --workers 2`) or cell by cell
(`# %%` cells, as in Jupyter or VS Code). The same `calibrate` runs on a laptop's LocalCluster
and on a real cluster: point `Client` at the scheduler instead.

Each simulated machine is the bundled `examples/xy_table.kin` with a random truth: its own
squareness and scale error, and a backlash of X the nominal model lacks. A task reads the
machine's model and measurement file, fits, diagnoses (which physical effect is missing),
writes FIT.json, FIT.params, DIAGNOSE.json and a short REPORT.md beside the data, and returns
one row: σ̂ and the RMS before, the RMS after the top finding's line, and that line. The fit
is weighted by the stated instrument noise, so σ̂ and the RMS are multiples of it (1 = the model
explains the data down to the noise).
"""

# %% Setup
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Dict, List

import numpy as np

import kin

HERE = Path(__file__).resolve().parent
NOMINAL = HERE.parent / "xy_table.kin"
# The truth adds what the nominal model does not have: a backlash of X.
TRUTH_EXTRA = "        X.tx += backlash(X)\n"
NOISE = 0.3e-6  # m: the instrument's stated noise


def truth_source() -> str:
    text = NOMINAL.read_text()
    at = text.rindex("    }\n}")  # the end of the errors block
    return text[:at] + TRUTH_EXTRA + text[at:]


# %% A fleet of simulated machines
def make_fleet(root: Path, machines: int, points: int = 400, seed: int = 2026) -> List[Path]:
    """`machines` folders under `root`, each with `machine.kin` (the nominal model) and
    `points.csv` simulated from its own random truth. Returns the folders."""
    rng = np.random.default_rng(seed)
    truth = kin.Model.compile(truth_source())
    nominal = NOMINAL.read_text()
    # SI scales of the truth's coefficients: squareness (rad), scale (m/m), backlash (m).
    scale = {"Y.rz[0]": 30e-6, "X.tx[0]": 10e-6, "X.tx[1]": 4e-6}
    dirs = []
    for i in range(machines):
        d = root / f"machine_{i:03d}"
        d.mkdir(parents=True, exist_ok=True)
        beta = np.array([rng.normal(0.0, scale.get(n, 1e-6)) for n in truth.coefficients])
        # Backlash is a half-width: positive.
        beta = np.where([n == "X.tx[1]" for n in truth.coefficients], np.abs(beta) + 2e-6, beta)
        kin.simulate(truth.with_beta(beta), d / "points.csv", points, noise=NOISE,
                     seed=seed + i, observe=["ex", "ey"])
        (d / "machine.kin").write_text(nominal)
        dirs.append(d)
    return dirs


# %% One task: everything about one machine
def calibrate(folder: str) -> Dict[str, object]:
    """Fits and diagnoses one machine's data, writes its files, returns its row of the table."""
    folder = Path(folder)
    model = kin.Model.from_file(str(folder / "machine.kin"))
    data = folder / "points.csv"
    diagnosis = kin.diagnose(model, data, noise=NOISE)
    fit = diagnosis.fit
    inputs = [folder / "machine.kin", data]
    fit.write(folder / "FIT.json", inputs=inputs)
    diagnosis.write(folder / "DIAGNOSE.json", inputs=inputs)
    top = diagnosis.top
    lines = [
        f"# {folder.name}",
        "",
        f"- rows: {fit.rows}, σ̂ = {fit.sigma:.4g} ({fit.error_unit}), RMS = {diagnosis.rms:.4g}",
        *[f"- {c.name} = {c.value:.4g} ± {c.se:.2g} {c.unit}" for c in fit.coefficients],
        f"- top finding: `{top.line}` — {top.explanation}" if top else "- no significant finding",
    ]
    kin._kin.write_files([(str(folder / "REPORT.md"), ("\n".join(lines) + "\n").encode())],
                         [str(p) for p in inputs])
    return {
        "machine": folder.name,
        "rows": fit.rows,
        "sigma_before": fit.sigma,
        "rms_before": diagnosis.rms,
        "rms_after": top.rms_after if top else diagnosis.rms,
        "top_finding": top.line if top else "",
    }


# %% The fleet on a cluster
def run_fleet(folders: List[Path], workers: int):
    """Calibrates every folder on a LocalCluster of `workers` processes: the table, and the
    wall time in seconds."""
    import pandas as pd
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        client.wait_for_workers(workers)
        start = time.perf_counter()
        futures = client.map(calibrate, [str(f) for f in folders], pure=False)
        rows = client.gather(futures)
        seconds = time.perf_counter() - start
    return pd.DataFrame(rows).sort_values("machine").reset_index(drop=True), seconds


def run_serial(folders: List[Path]):
    import pandas as pd

    rows = [calibrate(str(f)) for f in folders]
    return pd.DataFrame(rows).sort_values("machine").reset_index(drop=True)


# %% Run
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--machines", type=int, default=50)
    p.add_argument("--points", type=int, default=400)
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--root", default="fleet")
    a = p.parse_args(argv)
    folders = make_fleet(Path(a.root), a.machines, a.points)
    for w in a.workers:
        table, seconds = run_fleet(folders, w)
        print(f"{w} worker(s): {len(folders)} machines in {seconds:.1f} s = "
              f"{60 * len(folders) / seconds:.1f} machines/min")
    print(table.to_string(max_colwidth=60))
    return 0


if __name__ == "__main__":
    sys.exit(main())
