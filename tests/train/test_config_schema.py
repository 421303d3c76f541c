"""uss-train's config against its schema (``train.train.check_config``, :mod:`uss_slam.core.schema`):
the run's own keys and every ``_target_`` node, one line naming the key."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

from uss_slam.core.cli import FailedJob, JobReport
from uss_slam.core.schema import MAX_THREADS, SchemaError
from uss_slam.train.train import MAX_SEED, RunSettings, check_config, draw_seed

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _compose(*overrides: str) -> DictConfig:
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
            return compose(
                "train", overrides=["experiment=ci", "paths.output_dir=/unused/out", *overrides]
            )
    finally:
        GlobalHydra.instance().clear()


def test_the_shipped_config_passes_and_gives_the_run_settings() -> None:
    settings = check_config(_compose("seed=7", "run_name=2024", "trainer.precision=auto"))
    assert isinstance(settings, RunSettings)
    assert (settings.seed, settings.run_name, settings.num_threads) == (7, "2024", None)


def test_seed_null_draws_a_seed_that_every_seed_key_takes() -> None:
    """``seed=null`` (documented as valid) used to be refused by ``data.seed: ${seed}``."""
    cfg = _compose("seed=null", "data=real")
    draw_seed(cfg)
    settings = check_config(cfg)
    assert settings.seed is not None and 0 <= settings.seed <= MAX_SEED
    assert cfg.data.seed == settings.seed


@pytest.mark.parametrize("data", ["real", "synthetic"])
def test_the_largest_seed_is_one_every_seed_key_takes(data: str) -> None:
    """A seed past a C int (``seed=null`` draws one half the time) reaches ``data.seed`` too."""
    settings = check_config(_compose(f"seed={MAX_SEED}", f"data={data}"))
    assert settings.seed == MAX_SEED


@pytest.mark.parametrize(
    ("override", "line"),
    [
        ("seed=abc", "seed: expected an integer >= 0 and <= 4294967295 or null, got 'abc'"),
        ("seed=-1", "seed: expected an integer >= 0 and <= 4294967295 or null, got -1"),
        (f"seed={MAX_SEED + 1}", f"seed: expected an integer >= 0 and <= {MAX_SEED} or null, "
                                 f"got {MAX_SEED + 1}"),
        ("num_threads=0", f"num_threads: expected an integer >= 1 and <= {MAX_THREADS} or null, "
                          "got 0"),
        ("num_threads=100000", f"num_threads: expected an integer >= 1 and <= {MAX_THREADS} or "
                               "null, got 100000"),
        ("+unknown=1", "unknown: unknown key; expected one of task_name, run_name, "),
        ("data.source.transform.crop_size=0",
         "data.source.transform.crop_size: expected a number >= 8, got 0"),
        ("data.target.transform.crop_size=8",
         "data.target.transform.crop_size: expected at least 16 px (2 ** "
         "model.method.discriminator.n_layers = 4), got 8"),
        ("model.poly_power=-1", "model.poly_power: expected a number > 0, got -1"),
        ("model.head_lr_mult=0", "model.head_lr_mult: expected a number > 0, got 0"),
        ("model.max_iters=0", "model.max_iters: expected an integer >= 1, got 0"),
        ("model.optimizer.momentum=-0.5", "model.optimizer.momentum: expected a number >= 0 "
                                          "and < 1, got -0.5"),
        ("trainer.log_every_n_steps=-1", "trainer.log_every_n_steps: expected an integer >= 1 "),
        ("model.class_names=[background,person,person,monitor]",
         "model.class_names: expected a list of strings, each once ('person' is listed twice)"),
        ("data.num_workers=100000", f"data.num_workers: expected an integer >= 0 and <= "
                                    f"{MAX_THREADS}, got 100000"),
        ("tags=5", "tags: expected a list of strings, got 5"),
        ("model.max_iters=abc", "model.max_iters: expected an integer >= 1, got 'abc'"),
        ("trainer.precision=15", "trainer.precision: expected one of "),
        ("+model.optimizer.rate=1", "model.optimizer.rate: unknown key; expected one of "),
        ("data.batch_size=2.5", "data.batch_size: expected an integer >= 1, got 2.5"),
    ],
)  # fmt: skip
def test_a_bad_value_is_one_line_naming_its_key(override: str, line: str) -> None:
    with pytest.raises(SchemaError) as caught:
        check_config(_compose(override))
    assert str(caught.value).startswith(line) and "\n" not in str(caught.value)


def _target(count: int, rate: float = 0.1, names: Sequence[str] = ()) -> None:
    """A stand-in target."""


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
