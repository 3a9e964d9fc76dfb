import runpy
import sys

from conftest import EXAMPLES


def test_the_notebook_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["notebook.py"])
    runpy.run_path(str(EXAMPLES / "python" / "notebook.py"), run_name="__main__")
    assert (tmp_path / "FIT.json").is_file()
