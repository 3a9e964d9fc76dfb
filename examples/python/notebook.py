"""kin from Python, cell by cell (`# %%` cells run in Jupyter, VS Code or as a script).

A two-axis table (`examples/xy_table.kin`) with a squareness and a scale error: simulate a
calibration, read it as a DataFrame, fit, look at the coefficients and residuals, diagnose,
evaluate the fitted model on a grid with numpy, and compensate.
"""

# %% Compile the model
from pathlib import Path

import numpy as np

import kin

HERE = Path(__file__).resolve().parent
model = kin.Model.from_file(str(HERE.parent / "xy_table.kin"))
print(model, model.axes, model.coefficients)

# %% Simulate a calibration run: 20 µrad squareness, 8 µm/m scale error, 0.3 µm noise
truth = model.with_beta(np.array([{"Y.rz[0]": 20e-6, "X.tx[0]": 8e-6}[n] for n in model.coefficients]))
kin.simulate(truth, "points.csv", 300, noise=0.3e-6, seed=1)
df = kin.read_measurements(model, "points.csv")
print(df.head())

# %% Fit: coefficients with standard errors, residuals as a DataFrame
fit = kin.fit(model, "points.csv", noise=0.3e-6)
print(fit.coefficient_table()[["value", "se", "unit"]])
print(f"σ̂/σ = {fit.sigma:.3f}")
print(fit.residuals.groupby("component")["residual"].std())
fit.write("FIT.json", inputs=["points.csv"])

# %% Diagnose: anything missing?
d = kin.diagnose(model, "points.csv", noise=0.3e-6)
print("top finding:", d.top.line if d.top else "none — the model explains the data")

# %% Evaluate the fitted model on a grid (SI units, no copies)
fitted = kin.Model.from_file(str(HERE.parent / "xy_table.kin"), "FIT.params")
y, x = np.meshgrid(np.linspace(0, 0.5, 11), np.linspace(0, 0.5, 11), indexing="ij")
states = np.ascontiguousarray(np.column_stack([y.ravel(), x.ravel()]))
err = np.empty((len(states), 6))
fitted.eval(states, out=err)
print(f"largest predicted position error: {np.abs(err[:, :3]).max() * 1e6:.2f} µm")

# %% Compensate: the joint corrections that cancel it
dq = fitted.compensate(states, position_only=True)
print(f"largest correction: {np.abs(dq).max() * 1e6:.2f} µm")
