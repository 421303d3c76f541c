"""``uss-experiments --help`` and a refused override answer without importing torch: the
config schema is read from the structured configs and the method configs, and torch,
torchvision and Lightning are imported only where a job trains (each costs seconds of CPU)."""

from __future__ import annotations

import subprocess
import sys

import pytest

# A fresh interpreter: the other tests' imports would hide one.
PROBE = """
import sys
from uss_slam.pipelines.experiments.cli import main
sys.argv = ["uss-experiments", *sys.argv[1:]]
try:
    main()
except SystemExit as stop:
    code = stop.code
else:
    code = 0
heavy = sorted(m for m in ("torch", "torchvision", "lightning") if m in sys.modules)
print("imported:", ",".join(heavy) or "none", "exit:", code, file=sys.stderr)
"""


@pytest.mark.parametrize(
    ("args", "code"),
    [
        (["--help"], 0),
        (["grid.seeds=[-1]"], 1),  # the schema's refusal
        (["grid.depth_sweep=[fda]"], 1),  # the methods with discriminators, from their classes
    ],
)
def test_help_and_refusals_import_no_torch(args: list[str], code: int) -> None:
    done = subprocess.run(
        [sys.executable, "-c", PROBE, *args], capture_output=True, text=True, timeout=120
    )
    last = done.stderr.strip().splitlines()[-1]
    assert last == f"imported: none exit: {code}", done.stderr[-2000:]
