"""uss-slam's config against its schema (``slam_eval.config.check``): one line per problem."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.config import check, register_configs

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SEMANTIC = "uss_slam.slam_eval.filters.semantic.SemanticFilter"


def _compose(*overrides: str) -> DictConfig:
    register_configs()
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
            return compose(
                "slam_eval",
                overrides=["sequence.path=/unused", "out_dir=/unused", *overrides],
            )
    finally:
        GlobalHydra.instance().clear()


def test_the_shipped_config_passes() -> None:
    plan = check(_compose("sequence.max_frames=5", "slam.repeats=2"))
    assert plan.runs == [(None, [])] and len(plan.repeats) == 2
    assert list(plan.filter_params) == ["semantic", "flow", "geometry", "object"]


@pytest.mark.parametrize(
    ("overrides", "line"),
    [
        (["sequence.start=-1"], "sequence.start: expected an integer >= 0, got -1"),
        (["sequence.max_frames=0"], "sequence.max_frames: expected an integer >= 2 or null, got 0"),
        (["slam.prefetch=-1"], "slam.prefetch: expected an integer >= 0 and <= 256, got -1"),
        (["slam.reader_threads=0"],
         "slam.reader_threads: expected an integer >= 1 and <= 8 or null, got 0"),
        (["slam.prefetch_mode=fork"],
         "slam.prefetch_mode: expected one of 'auto', 'thread', 'process', got 'fork'"),
        (["slam.filter_params.object.classes=person"],
         "slam.filter_params.object.classes: expected a list of strings or null, got 'person'"),
        (["slam.filter_params.flow.window=2.5"],
         "slam.filter_params.flow.window: expected an integer >= 3 and <= 255, got 2.5"),
        # a filter added with its own _target_ is checked against that class
        ([f"+slam.filter_params.wide._target_={SEMANTIC}", "+slam.filter_params.wide.dilation=abc"],
         "slam.filter_params.wide.dilation: expected an integer >= 0, got 'abc'"),
        # rules across keys stay checks of their own, naming the key
        (["slam.orb.min_fast=30"], "slam.orb.min_fast: expected an integer <= slam.orb.ini_fast (20), got 30"),
    ],
)  # fmt: skip
def test_a_bad_value_is_one_line_naming_its_key(overrides: list[str], line: str) -> None:
    with pytest.raises(UssSlamError) as caught:
        check(_compose(*overrides))
    assert str(caught.value) == line
