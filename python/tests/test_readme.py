"""The README's Python block, run as written from the repository's root: a snippet a new user
copies must work (it once read a file that did not exist)."""

import os
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[2]


def test_the_readme_python_block_runs_as_written(capsys):
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "the README has no Python block"
    here = os.getcwd()
    os.chdir(ROOT)
    try:
        for block in blocks:
            exec(compile(block, "README.md", "exec"), {})
    finally:
        os.chdir(here)
    # The block ends by printing the fit and the rows read: the bundled data, fitted.
    out = capsys.readouterr().out
    assert "<kin.FitResult bridge_cmm:" in out, out
