import json

import numpy as np

import kin
from conftest import EXAMPLES

XY = EXAMPLES / "xy_table.kin"


def test_fit_recovers_a_simulated_truth_with_standard_errors(tmp_path):
    m = kin.Model.from_file(str(XY))
    truth = {"Y.rz[0]": 20e-6, "X.tx[0]": 8e-6}
    kin.simulate(m.with_beta(np.array([truth[n] for n in m.coefficients])), tmp_path / "d.csv",
                 400, noise=0.3e-6, seed=11)
    r = kin.fit(m, tmp_path / "d.csv")
    assert r.rows == 1200
    assert 0.2 < r.sigma < 0.4  # µm: the simulated noise
    by = {c.name: c for c in r.coefficients}
    # Display units: urad and um/m; the truth within 5 standard errors.
    assert abs(by["Y.rz[0]"].value - 20) < 5 * by["Y.rz[0]"].se
    assert abs(by["X.tx[0]"].value - 8) < 5 * by["X.tx[0]"].se
    assert set(r.residuals.columns) >= {"line", "component", "residual", "studentized"}
    assert len(r.residuals) == 1200
    r.write(tmp_path / "FIT.json", inputs=[XY, tmp_path / "d.csv"])
    doc = json.loads((tmp_path / "FIT.json").read_text())
    assert doc["sigma"] == r.sigma
    assert (tmp_path / "FIT.params").read_text() == r.params
    # The fitted parameters bind back into the model.
    fitted = kin.Model.from_file(str(XY), str(tmp_path / "FIT.params"))
    assert np.allclose(fitted.beta * 1e6, [by[n].value for n in m.coefficients], rtol=1e-9)


def test_diagnose_names_the_missing_effect_with_its_line(tmp_path):
    # The truth has a backlash of X; the nominal model does not.
    src = XY.read_text()
    at = src.rindex("    }\n}")
    truth = kin.Model.compile(src[:at] + "        X.tx += backlash(X)\n" + src[at:])
    beta = np.array([{"Y.rz[0]": 20e-6, "X.tx[0]": 8e-6, "X.tx[1]": 5e-6}[n] for n in truth.coefficients])
    kin.simulate(truth.with_beta(beta), tmp_path / "d.csv", 400, noise=0.3e-6, seed=3,
                 observe=["ex", "ey"])
    d = kin.diagnose(str(XY), tmp_path / "d.csv", noise=0.3e-6)
    assert d.top is not None
    assert "backlash(X)" in d.top.line and d.top.line.startswith("X.tx")
    assert d.top.rms_after < d.rms
    assert d.fit.sigma > 2  # σ̂/σ: the nominal model fails
    # Printed, a result is a line, not the megabytes of its document; notebooks get a table.
    for shown in (repr(d), repr(d.fit)):
        assert len(shown) < 300 and shown.startswith("<kin."), shown
    assert "backlash(X)" in repr(d)
    assert "<table>" in d._repr_html_() and "<table>" in d.fit._repr_html_()


def test_the_package_says_its_version_and_its_errors_are_kin_s():
    assert kin.__version__.count(".") == 2
    assert kin.KinError.__module__ == "kin"
    try:
        kin.Model.compile("machine {")
    except kin.CompileError as e:
        assert type(e).__module__ == "kin" and type(e).__name__ == "CompileError"
    else:
        raise AssertionError("no error")
