"""The worked examples of docs/extending.md, run as written: every fenced block that starts with
``# file: PATH`` is written to ``PATH`` under a temporary folder (on ``sys.path`` / ``PYTHONPATH``)
and used by one test below; a block that no test uses fails :func:`test_every_snippet_is_run`."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from shared_helpers import compose_train, data_overrides

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "extending.md"
BLOCK = re.compile(r"^```[a-z]*\n# file: (\S+)\n(.*?)^```$", re.M | re.S)
USED = {
    "my_uss/entropy_method.py",
    "my_configs/model/method/target_entropy.yaml",
    "my_uss/border_filter.py",
    "run_border_filter.sh",
    "my_uss/dark_segmenter.py",
    "my_configs/segmenter/dark.yaml",
    "my_uss/oracle_system.py",
    "my_uss/presets.py",
}
"""The snippets the tests below run (by their ``# file:`` path)."""


def snippets() -> dict[str, str]:
    """``{path: text}`` of the doc's ``# file:`` blocks (the ``# file:`` line included)."""
    found: dict[str, str] = {}
    for match in BLOCK.finditer(DOC.read_text(encoding="utf-8")):
        path, body = match.group(1), match.group(2)
        assert path not in found, f"docs/extending.md: two blocks write {path}"
        found[path] = f"# file: {path}\n{body}"
    return found


@pytest.fixture
def examples(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Every snippet written under ``tmp_path / "ext"``, which is put first on ``sys.path``;
    the ``my_uss`` modules are forgotten afterwards."""
    root = tmp_path / "ext"
    for path, text in snippets().items():
        target = root / path
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text, encoding="utf-8")
    (root / "my_uss" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(root))
    yield root
    for name in [m for m in sys.modules if m == "my_uss" or m.startswith("my_uss.")]:
        del sys.modules[name]


def test_every_snippet_is_run() -> None:
    assert set(snippets()) == USED


def test_a_new_method_joins_the_list_and_trains(
    examples: Path, uda_data: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import torch
    from hydra.utils import instantiate
    from lightning.pytorch import Trainer

    from uss_slam.train import method_configs

    # The YAML in (a copy of) the shipped group: one more method for the grid and the tests.
    group = tmp_path / "method"
    group.mkdir()
    for path in method_configs.METHOD_GROUP.glob("*.yaml"):
        (group / path.name).write_text(path.read_text())
    yaml_file = examples / "my_configs" / "model" / "method" / "target_entropy.yaml"
    (group / yaml_file.name).write_text(yaml_file.read_text())
    monkeypatch.setattr(method_configs, "METHOD_GROUP", group)
    method_configs.method_target.cache_clear()
    try:
        names = method_configs.method_names()
        assert names[0] == "source_only" and "target_entropy" in names
        from my_uss.entropy_method import TargetEntropy

        assert method_configs.method_class("target_entropy") is TargetEntropy
        assert not method_configs.trains_discriminators("target_entropy")
    finally:
        method_configs.method_target.cache_clear()

    # The doc's uss-train overrides: two iterations of experiment=ci.
    overrides = [
        f"hydra.searchpath=[file://{examples / 'my_configs'}]",
        "model/method=target_entropy",
        "experiment=ci",
        *data_overrides(uda_data),
        "logger=none",
    ]
    cfg = compose_train(overrides, tmp_path / "run")
    model = instantiate(cfg.model)
    assert isinstance(model.method, TargetEntropy) and model.method.weight == 0.5
    assert model.method.discriminators is None
    before = {k: v.clone() for k, v in model.segmenter.state_dict().items()}
    trainer = Trainer(
        accelerator="cpu", max_epochs=1, limit_val_batches=0, logger=False, log_every_n_steps=1,
        enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
    )  # fmt: skip
    trainer.fit(model, datamodule=instantiate(cfg.data))
    assert model.iteration == cfg.data.iterations_per_epoch == 2
    after = model.segmenter.state_dict()
    assert not all(torch.equal(after[k], v) for k, v in before.items())
    logged = set(trainer.callback_metrics) | set(trainer.logged_metrics)
    assert {"train/loss_ent_trg_main", "train/loss_seg_src_main"} <= logged


def _uss_slam_env(examples: Path, seq: Path, out: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(examples), env.get("PYTHONPATH", "")])
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    return {**env, "SEQ": str(seq), "OUT": str(out)}


def test_a_new_filter_runs_in_uss_slam(examples: Path, synthetic_sequence, tmp_path: Path) -> None:
    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    out = tmp_path / "out"
    script = examples / "run_border_filter.sh"
    done = subprocess.run(
        ["bash", str(script)], env=_uss_slam_env(examples, seq, out), capture_output=True,
        text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 8 and metrics["settings"]["filters"] == ["border"]
    assert metrics["keypoints"]["dropped"]["border"] > 0

    # Its declared range, as one line naming the key: the script with a negative margin.
    bad = tmp_path / "bad.sh"
    bad.write_text(script.read_text().replace("margin: 20", "margin: -1"))
    done = subprocess.run(
        ["bash", str(bad)], env=_uss_slam_env(examples, seq, tmp_path / "bad"),
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 1
    assert "slam.filter_params.border.margin: expected a number >= 0, got -1" in done.stderr


def test_the_filter_flags_exactly_the_border(examples: Path) -> None:
    from types import SimpleNamespace

    from my_uss.border_filter import BorderFilter

    class Keypoints:
        xy = np.array([[5.0, 50.0], [50.0, 50.0], [95.0, 50.0], [50.0, 79.5]], np.float32)

        def __len__(self) -> int:
            return len(self.xy)

    frame = SimpleNamespace(gray=np.zeros((80, 100), np.uint8))
    out = BorderFilter(margin=10)(SimpleNamespace(frame=frame, features=Keypoints()))
    assert out.dynamic.tolist() == [True, False, True, True] and out.checked == 4


def test_a_new_segmenter_runs_on_a_frame(examples: Path, synthetic_sequence) -> None:
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from uss_slam.core.errors import UssSlamError
    from uss_slam.slam_eval.sequence import TumSequence

    node = OmegaConf.load(examples / "my_configs" / "segmenter" / "dark.yaml")
    segmenter = instantiate(node)
    frame = TumSequence(synthetic_sequence(preset="walking_xyz", frames=30), max_frames=1).load(0)
    labels = segmenter.segment(frame)
    assert labels.shape == frame.gray.shape and labels.dtype == np.uint8
    dark = frame.rgb.max(axis=2) < 40
    assert np.array_equal(labels == 1, dark) and set(np.unique(labels)) <= {0, 1}
    with pytest.raises(UssSlamError, match="segmenter.threshold must be in 0..255, got 300"):
        type(segmenter)(threshold=300)


def test_a_new_system_is_scored_as_the_shipped_ones(examples: Path, synthetic_sequence) -> None:
    from my_uss.oracle_system import run_oracle

    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    trajectory, evaluation = run_oracle(str(seq))
    assert len(trajectory) == 30 and evaluation.error is None
    assert evaluation.ate.stats.pairs == 30 and evaluation.ate.stats.rmse < 1e-3
    trajectory, evaluation = run_oracle(str(seq), max_frames=2)
    assert evaluation.ate is None and "ATE needs 3 poses" in evaluation.error


def test_a_new_preset_renders(
    examples: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from my_uss.presets import SITTING_RPY

    from uss_slam.slam_eval.sequence import TumSequence
    from uss_slam.synthetic import PRESETS, render_sequence

    assert SITTING_RPY.name not in PRESETS
    monkeypatch.setitem(PRESETS, SITTING_RPY.name, SITTING_RPY)
    out = render_sequence(tmp_path / "seq", preset="sitting_rpy", frames=3, size=(80, 60))
    sequence = TumSequence(out, load_labels=True)
    assert len(sequence) == 3 and sequence.load(2).labels.shape == (60, 80)
    assert "preset: sitting_rpy" in (out / "synthetic.yaml").read_text()
