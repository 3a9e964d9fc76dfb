import cloudpickle
import numpy as np
import pandas as pd

import fleet


def test_a_fleet_on_a_dask_cluster_matches_serial_runs(tmp_path):
    # Workers import `kin`, not this folder: `calibrate` travels by value.
    cloudpickle.register_pickle_by_value(fleet)
    folders = fleet.make_fleet(tmp_path / "fleet", machines=50, points=300)
    table, seconds = fleet.run_fleet(folders, workers=2)
    assert len(table) == 50
    for f in folders:
        for name in ("FIT.json", "FIT.params", "DIAGNOSE.json", "REPORT.md"):
            assert (f / name).is_file()
    serial = fleet.run_serial(folders)
    pd.testing.assert_frame_equal(table, serial, check_exact=False, rtol=1e-12)
    # Most machines' missing backlash is found (the truths' backlash is ≥ 2 µm, noise 0.3 µm).
    found = table["top_finding"].str.contains("backlash(X)", regex=False).mean()
    assert found > 0.9
    assert (table["rms_after"] < table["rms_before"]).mean() > 0.9
