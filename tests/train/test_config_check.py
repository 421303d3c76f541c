"""Config values against parameter annotations (``uss_slam.train.config_check``)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from typing import Any, Literal

import pytest
from omegaconf import OmegaConf
from torch import Tensor

from uss_slam.core.cli import FailedJob, JobReport
from uss_slam.core.errors import UssSlamError
from uss_slam.train.config_check import accepts, check_node, describe


@pytest.mark.parametrize(
    ("annotation", "value", "verdict"),
    [
        (int, 3, True),
        (int, True, False),  # a boolean is no count
        (int, 2.5, False),
        (int, "3", False),
        (float, 3, True),
        (float, "fast", False),
        (bool, 1, False),
        (str, "x", True),
        (int | None, None, True),
        (int | None, "x", False),
        (float | Tensor, "x", False),
        (float | Tensor, 0.1, True),
        (Literal[16, 32, "bf16"], 32, True),
        (Literal[16, 32, "bf16"], "32", False),
        (Sequence[int], [1, 2], True),
        (Sequence[int], [1, "x"], False),
        (Sequence[int], "12", False),
        (tuple[float, float], [0.9, 0.99], True),
        (tuple[float, float], [0.9], False),
        (tuple[int, ...], [1, 2, 3], True),
        (dict[str, Any], {"a": 1}, True),
        (dict[str, Any], [1], False),
        (Any, "x", None),
        (Tensor | object, "x", None),  # a class a config cannot judge
        (str | object, 3, None),
    ],
)
def test_accepts(annotation: Any, value: Any, verdict: bool | None) -> None:
    assert accepts(annotation, value) is verdict


def test_describe() -> None:
    assert describe(int | None) == "an integer or null"
    assert describe(Sequence[str]) == "a list of strings"
    assert describe(float | Tensor) == "a number"
    assert describe(Literal[1, "a"]) == "one of 1, 'a'"


def _target(count: int, rate: float = 0.1, names: Sequence[str] = ()) -> None:
    """A stand-in target for the node checks."""


def test_check_node_names_the_key_and_recurses() -> None:
    target = f"{__name__}._target"
    good = OmegaConf.create({"a": {"_target_": target, "count": 2, "inner": {"_target_": target}}})
    with pytest.raises(UssSlamError, match=r"a\.inner: .*takes no argument 'inner'"):
        check_node(good, "")
    node = OmegaConf.create({"_target_": target, "count": 2, "names": ["x", 3]})
    with pytest.raises(
        UssSlamError, match=r"^m\.names: expected a list of strings, got \['x', 3\]$"
    ):
        check_node(node, "m")
    nested = OmegaConf.create({"m": {"list": [{"_target_": target, "count": "many"}]}})
    with pytest.raises(UssSlamError, match=r"^m\.list\[0\]\.count: expected an integer"):
        check_node(nested, "")
    missing = OmegaConf.create({"_target_": target, "count": "???", "rate": "${rate2}", "rate2": 1})
    with pytest.raises(UssSlamError, match="takes no argument 'rate2'"):
        check_node(missing, "m")  # ??? is left to Hydra; the interpolation resolves to 1
    check_node(OmegaConf.create({"_target_": "no.such.Thing", "x": 1}), "m")  # left to Hydra


def test_job_report_lists_what_tells_the_failed_jobs_apart() -> None:
    report = JobReport("uss-x", started=3)
    report.overrides = [("a=1", "b=1"), ("a=1", "b=2"), ("a=1", "b=3")]
    report.failures = [FailedJob(0, ("a=1", "b=1"), "uss-x: error: bad b"),
                       FailedJob(2, ("a=1", "b=3"), "uss-x: error: worse b")]  # fmt: skip
    assert report.summary().splitlines() == [
        "uss-x: 2 of 3 jobs failed:",
        "  #0 b=1: uss-x: error: bad b",
        "  #2 b=3: uss-x: error: worse b",
    ]


def test_core_cli_imports_neither_hydra_nor_torch() -> None:
    code = "import sys, uss_slam.core.cli; print(sorted({'hydra', 'omegaconf', 'torch'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
