"""``uss-demo`` options that need no training: ``--train-threads`` reaches both trainings."""

from __future__ import annotations

from pathlib import Path

import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.pipelines import demo


def test_train_threads_override_only_when_given() -> None:
    plan = demo.PLANS["demo"]
    default = demo.train_overrides(plan, Path("/d"), "adapted")
    assert not any(o.startswith("num_threads=") for o in default)
    one = demo.train_overrides(plan, Path("/d"), "source_only", threads=1)
    assert one[: len(default)] == [o.replace("true", "false") for o in default[:2]] + [
        "paths.data_dir=/d",
        "run_name=demo_source_only",
    ]
    assert one[-1] == "num_threads=1"


def test_train_threads_option() -> None:
    parser = demo.build_parser()
    assert parser.parse_args([]).train_threads is None
    assert parser.parse_args(["--train-threads", "1"]).train_threads == 1
    with pytest.raises(UssSlamError, match="--train-threads must be >= 1, got 0"):
        demo.run_demo(Path("/nonexistent"), train_threads=0)
