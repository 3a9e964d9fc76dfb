import numpy as np
import pandas as pd
import pytest

import kin
from conftest import EXAMPLES

XY = EXAMPLES / "xy_table.kin"


def truth():
    m = kin.Model.from_file(str(XY))
    beta = np.array([{"Y.rz[0]": 20e-6, "X.tx[0]": 8e-6}[n] for n in m.coefficients])
    return m.with_beta(beta)


def test_measurements_round_trip_through_a_dataframe(tmp_path):
    m = truth()
    kin.simulate(m, tmp_path / "a.csv", 100, noise=0.2e-6, seed=1)
    df = kin.read_measurements(m, tmp_path / "a.csv")
    # The header's own names, values in the file's units.
    assert list(df.columns) == ["Y[mm]", "X[mm]", "ex[um]", "ey[um]", "ez[um]"]
    assert len(df) == 100
    assert df["X[mm]"].between(0, 500).all()
    kin.write_measurements(df, m, tmp_path / "b.csv", comments=["copied"])
    back = kin.read_measurements(m, tmp_path / "b.csv")
    pd.testing.assert_frame_equal(df, back, check_exact=True)
    # The same data fit to the same numbers.
    a = kin.fit(m, tmp_path / "a.csv")
    b = kin.fit(m, tmp_path / "b.csv")
    assert [c.value for c in a.coefficients] == [c.value for c in b.coefficients]


def test_a_semicolon_file_with_decimal_commas_reads(tmp_path):
    p = tmp_path / "s.csv"
    p.write_text("# a spreadsheet's export\nY[mm];X[mm];ex[um]\n10,5;20;0,25\n\n30;40,25;-1,5\n")
    df = kin.read_measurements(kin.Model.from_file(str(XY)), p)
    assert df["Y[mm]"].tolist() == [10.5, 30.0]
    assert df["X[mm]"].tolist() == [20.0, 40.25]
    assert df["ex[um]"].tolist() == [0.25, -1.5]


def test_a_wrong_file_is_a_located_data_error(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("# header next\nY[mm],X[mm],ex[um]\n1,2,3\n4,oops,6\n")
    with pytest.raises(kin.DataError) as e:
        kin.read_measurements(kin.Model.from_file(str(XY)), p)
    assert e.value.path == str(p)
    assert e.value.line == 4
    assert e.value.column == 3  # characters, as kin reports it: `oops` starts at column 3
    assert e.value.problems


def test_a_frame_that_would_not_read_back_is_not_written(tmp_path):
    m = kin.Model.from_file(str(XY))
    target = tmp_path / "keep.csv"
    target.write_text("precious\n")
    df = pd.DataFrame({"Y[mm]": [1.0], "W[mm]": [2.0], "ex[um]": [0.1]})
    with pytest.raises(kin.DataError):
        kin.write_measurements(df, m, target)
    assert target.read_text() == "precious\n"


def test_an_output_never_names_an_input(tmp_path):
    m = truth()
    kin.simulate(m, tmp_path / "a.csv", 50, seed=2)
    r = kin.fit(m, tmp_path / "a.csv")
    before = (tmp_path / "a.csv").read_bytes()
    with pytest.raises(kin.KinError):
        r.write(tmp_path / "a.csv", inputs=[tmp_path / "a.csv"])
    assert (tmp_path / "a.csv").read_bytes() == before
