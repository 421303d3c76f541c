"""Best-checkpoint tracking across ``ckpt_path=last``: the resumed run keeps the earlier run's
best score and file, and replaces them only with a better one."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from omegaconf import open_dict
from shared_helpers import compose_train, data_overrides

from uss_slam.train.train import train


def _best_state(last: Path) -> dict:
    callbacks = torch.load(last, weights_only=False)["callbacks"]
    (state,) = [s for k, s in callbacks.items() if "val/score" in k]
    return state


def _run(uda_data: dict[str, Path], tmp_path: Path, name: str, scores: list[float], *extra: str):
    logs = tmp_path / "logs"
    cfg = compose_train(
        [
            "experiment=ci",
            *data_overrides(uda_data),
            "logger=none",
            "+trainer.limit_val_batches=1",
            "callbacks.model_checkpoint.monitor=val/score",
            "+callbacks.score._target_=train_helpers.ScriptedScore",
            f"+callbacks.score.scores={scores}",
            "+callbacks.score.iterations_per_epoch=2",
            *extra,
        ],
        logs / "train" / "runs" / "ci" / name,
    )
    with open_dict(cfg):
        cfg.paths.log_dir = str(logs)
    train(cfg)
    return logs / "train" / "runs" / "ci" / name / "checkpoints"


@pytest.mark.slow
@pytest.mark.parametrize(("scores", "best_in_first"), [([0.9, 0.5], True), ([0.5, 0.9], False)])
def test_best_checkpoint_survives_resume(
    scores: list[float], best_in_first: bool, uda_data: dict[str, Path], tmp_path: Path
) -> None:
    # Interrupted after epoch 1 (iteration 2), resumed in a new run folder for epoch 2.
    first = _run(uda_data, tmp_path, "first", scores, "trainer.max_epochs=1")
    (first_best,) = first.glob("best_*.ckpt")
    assert "iter0000002" in first_best.name
    second = _run(uda_data, tmp_path, "second", scores, "ckpt_path=last")

    state = _best_state(second / "last.ckpt")
    assert torch.load(second / "last.ckpt", weights_only=True)["iteration"] == 4
    second_best = sorted(second.glob("best_*.ckpt"))
    if best_in_first:
        assert state["best_model_path"] == str(first_best)
        assert float(state["best_model_score"]) == pytest.approx(0.9)
        assert second_best == []  # 0.5 after resuming is not a new best
    else:
        assert [p.name[:15] for p in second_best] == ["best_iter000000"]
        assert "iter0000004" in second_best[0].name
        assert state["best_model_path"] == str(second_best[0])
        assert float(state["best_model_score"]) == pytest.approx(0.9)
    assert first_best.is_file()  # the earlier run's files are never deleted
