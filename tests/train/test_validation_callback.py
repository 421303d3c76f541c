"""The training side of the label-free validators: the BatchNorm-statistics distance against a
plain re-statement, the callback's scores against the core validators fed by hand, and a tiny
training that logs them and keeps the checkpoint a validator selects."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from omegaconf import open_dict
from shared_helpers import compose_train, data_overrides
from torch import nn

from uss_slam.core.errors import UssSlamError
from uss_slam.core.validators import Entropy, SoftNeighborhoodDensity, downsample_maps
from uss_slam.train.validation import BatchNormDistance, TargetValidators


class TinySeg(nn.Module):
    """conv -> BatchNorm -> conv to 3 classes; ``net(x).main`` as the segmenters return it."""

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.conv = nn.Conv2d(3, 2, 3, padding=1)
        self.bn = nn.BatchNorm2d(2)
        self.head = nn.Conv2d(2, 3, 1)

    def forward(self, x: torch.Tensor) -> SimpleNamespace:
        return SimpleNamespace(main=self.head(self.bn(self.conv(x))))


class Images(torch.utils.data.Dataset):
    def __init__(self, seed: int, n: int = 6, shift: float = 0.0) -> None:
        g = torch.Generator().manual_seed(seed)
        self.x = torch.randn(n, 3, 12, 16, generator=g) + shift

    def __len__(self) -> int:
        return len(self.x)

    def __getitem__(self, i: int) -> dict:
        return {"image": self.x[i], "label": torch.zeros(12, 16, dtype=torch.long)}


def test_bn_distance_is_gaussian_w2_of_layer_inputs():
    net = TinySeg().eval()
    src, trg = Images(1).x, Images(2, shift=0.7).x
    with BatchNormDistance(net) as bn, torch.no_grad():
        bn.domain("source")
        net(src[:4])
        net(src[4:])
        bn.domain("target")
        net(trg)
        bn.domain(None)
        net(trg + 5)  # not recorded
    with torch.no_grad():
        fs, ft = net.conv(src).double(), net.conv(trg).double()
    total = 0.0
    for c in range(2):
        a, b = fs[:, c].flatten(), ft[:, c].flatten()
        sd = lambda v: math.sqrt(float(((v - v.mean()) ** 2).mean()))  # noqa: E731 population
        total += math.sqrt(float(a.mean() - b.mean()) ** 2 + (sd(a) - sd(b)) ** 2)
    assert bn.score() == pytest.approx(total / 2, rel=1e-9)
    assert not net.bn._forward_hooks  # hooks removed


def test_callback_scores_equal_core_validators_fed_by_hand():
    net = TinySeg().train()
    target, source = Images(3), Images(4, shift=1.0)
    cb = TargetValidators(names=["entropy", "snd", "probe"], params={"probe": {"folds": 2}},
                          bn_distance=True, frames=5, source_frames=4, source=source,
                          batch_size=2, max_side=8)  # fmt: skip
    scores = cb.compute(net, target)
    assert net.training  # restored
    assert list(scores) == ["entropy", "snd", "probe", "bn_distance"]
    ent, snd = Entropy(), SoftNeighborhoodDensity()
    net.eval()
    with torch.no_grad():
        idx = [0, 1, 2, 3, 4]  # five of six, evenly spaced
        x = target.x[[(k * 6) // 5 for k in idx]]
        prob = F.softmax(net(x).main, dim=1).numpy()
    small = downsample_maps(prob, 8)
    for k in range(0, 5, 2):
        ent.update(small[k : k + 2])
        snd.update(small[k : k + 2])
    assert scores["entropy"] == pytest.approx(ent.score(), rel=1e-5)
    assert scores["snd"] == pytest.approx(snd.score(), rel=1e-5)
    assert 0.0 <= scores["probe"] <= 1.0 and scores["bn_distance"] > 0


def test_callback_bad_settings_are_one_line():
    with pytest.raises(
        UssSlamError, match="callbacks.target_validators.frames: expected an integer >= 1"
    ):
        TargetValidators(frames=0)
    with pytest.raises(UssSlamError, match="unknown validator 'nope'"):
        TargetValidators(names=["nope"])
    with pytest.raises(UssSlamError, match="select: 'im' is not one of the computed validators"):
        TargetValidators(names=["entropy"], select="im")


@pytest.mark.slow
def test_training_logs_validators_and_keeps_the_selected_checkpoint(
    uda_data: dict[str, Path], tmp_path: Path
) -> None:
    from uss_slam.train.train import train

    out = tmp_path / "run"
    cfg = compose_train(
        ["experiment=ci", *data_overrides(uda_data), "logger=csv",
         "callbacks.target_validators.select=probe", "callbacks.target_validators.every_n_iterations=1"],
        out,
    )  # fmt: skip
    with open_dict(cfg):
        cfg.paths.output_dir = str(out)
        cfg.pop(
            "hydra", None
        )  # HydraConfig holds it (compose_train set it); uss-train never sees it
    train(cfg)
    assert (out / "checkpoints" / "validator_probe.ckpt").is_file()
    saved = torch.load(out / "checkpoints" / "validator_probe.ckpt", weights_only=False)
    assert saved["iteration"] in (2, 4)
    rows = [line.split(",") for line in next(out.rglob("metrics.csv")).read_text().splitlines()]
    header = rows[0]
    for name in ("entropy", "im", "snd", "probe", "dynamic_share", "bn_distance"):
        col = header.index(f"train/validator_{name}")
        values = [float(r[col]) for r in rows[1:] if r[col]]
        assert len(values) == 2 and all(np.isfinite(values)), name
