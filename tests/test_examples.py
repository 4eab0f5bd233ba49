"""Every example runs headless (each in its own process: it makes its own GL context)."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("[0-9][0-9]_*.py"))


@pytest.mark.parametrize("script", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs(script, tmp_path):
    # The examples keep their output in a fresh temporary folder for the user to look at; under the
    # test it goes into pytest's own tmp_path (TMPDIR), which pytest prunes, not into /tmp for good.
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600,
                         cwd=tmp_path, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stdout.strip(), "an example must say what it did"


def test_score_example_finds_the_truth():
    sys.path.insert(0, str(EXAMPLES[0].parent))
    res = subprocess.run([sys.executable, "-c", "import importlib; m = importlib.import_module("
                          "'01_score_candidates'); assert m.main() == 0"],
                         capture_output=True, text=True, cwd=EXAMPLES[0].parent, timeout=300)
    assert res.returncode == 0, res.stderr
