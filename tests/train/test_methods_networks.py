"""Every adaptation method trains every two-head segmenter: one iteration of each shipped
``model/method`` (every option of the config group: a new method is found without an edit here) with ``model/net=deeplab_small`` and ``pspnet_small`` (tiny crops)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from shared_helpers import compose_train
from train_helpers import fit_repeated

from uss_slam.models import SEGMENTERS
from uss_slam.testing import reference_step as bench
from uss_slam.train.method_configs import method_names

NETS = {"deeplab_small": "DeepLabV2", "pspnet_small": "PSPNet"}


@pytest.mark.parametrize("net", sorted(NETS))
@pytest.mark.parametrize("method", method_names())
def test_one_iteration_of_every_method_on_every_network(
    method: str, net: str, tmp_path: Path
) -> None:
    cfg = compose_train(["experiment=ci", f"model/method={method}", f"model/net={net}"], tmp_path)
    torch.manual_seed(0)
    model = instantiate(cfg.model)
    assert isinstance(model.segmenter, SEGMENTERS)
    assert type(model.segmenter).__name__ == NETS[net] and model.method.name == method
    seg_before = copy.deepcopy(model.segmenter.state_dict())
    discriminators = model.method.discriminators
    assert (discriminators is not None) is model.method.trains_discriminators
    d_before = copy.deepcopy(discriminators[1].state_dict()) if discriminators else None
    fit_repeated(model, bench.random_batch(33, 2), 1)
    assert model.iteration == 1
    after = model.segmenter.state_dict()
    assert all(torch.isfinite(v).all() for v in after.values() if v.is_floating_point())
    assert not all(torch.equal(v, seg_before[k]) for k, v in after.items())
    if d_before is not None:
        assert not all(
            torch.equal(v, d_before[k]) for k, v in model.method.d_main.state_dict().items()
        )
