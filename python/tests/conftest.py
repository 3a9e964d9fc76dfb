import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
sys.path.insert(0, str(EXAMPLES / "python"))


def kin_binary():
    """The `kin` command-line tool built by cargo (CI builds it before the Python step), or one
    named by $KIN_BIN; None when there is none."""
    for c in [os.environ.get("KIN_BIN"), ROOT / "target/debug/kin", ROOT / "target/release/kin",
              shutil.which("kin")]:
        if c and Path(c).is_file():
            return str(c)
    return None


@pytest.fixture
def kin_bin():
    b = kin_binary()
    if b is None:
        pytest.skip("no `kin` binary: build it with `cargo build --bin kin` or set KIN_BIN")
    return b
