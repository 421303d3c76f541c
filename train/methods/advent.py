"""ADVENT (AdvEnt): adversarial training on weighted self-information maps (Vu et al., CVPR 2019,
multi-level as in its code, valeoai/ADVENT).

The same iteration as AdaptSegNet (:mod:`.adaptsegnet`) with one change: the discriminators see
the *weighted self-information map* ``I = -P·log P / log C`` of each head (per class, ``P`` the
softmax of the logits upsampled to image size, ``C`` classes; ADVENT's ``prob_2_entropy``) instead
of ``P``. Summed over classes ``I`` is the normalised entropy (0..1): the target is pushed
towards the low-entropy, confident predictions of the source.

One iteration:

1. source forward, ``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)``;
2. target forward, ``L_adv = λ_adv_aux·BCE(D_aux(I_aux), 0) + λ_adv_main·BCE(D_main(I_main), 0)``
   with the discriminators frozen; one SGD step of the segmenter;
3. + 4. discriminators on the detached source (label 0) and target (label 1) maps ``I``.

ADVENT's weights (``configs/model/method/advent.yaml``, ``model.method.lambda_adv_*``): ``λ_adv_main
0.001, λ_adv_aux 0.0002`` (its ``LAMBDA_ADV_MAIN`` / ``LAMBDA_ADV_AUX``), equal to AdaptSegNet's
multi-level ones (its code's ``LAMBDA_ADV_TARGET2`` / ``LAMBDA_ADV_TARGET1``). The USS-SLAM paper's
weights, this project's defaults for ``adaptsegnet`` (``0.01`` / ``0.002``), are ten times both. Unlike ADVENT's code the discriminator losses are not halved (Adam is invariant to that
scale) and the optimisers are the project's (ADVENT: SGD without Nesterov, weight decay 5e-4).
"""

from __future__ import annotations

from typing import ClassVar

import torch.nn.functional as F
from torch import Tensor

from uss_slam.train.losses import self_information
from uss_slam.train.methods.adversarial import AdversarialMethod


class AdvEnt(AdversarialMethod):
    """``model/method=advent``: AdaptSegNet's iteration with the discriminators on the weighted
    self-information maps; loss weights ``model.method.lambda_adv_*`` (ADVENT's by default). The same
    logged keys as AdaptSegNet (``train/loss_adv_trg_*``, ``train/loss_d_*``, ``train/d_acc_*``)."""

    name: ClassVar[str] = "advent"

    def target_map(self, logits: Tensor) -> Tensor:
        return self_information(F.log_softmax(logits, dim=1))

    def source_map(self, log_probs: Tensor) -> Tensor:
        return self_information(log_probs)
