"""AdaptSegNet: adversarial output-space adaptation with two discriminators (the paper's
Algorithm 1; Tsai et al. 2018, multi-level): the discriminators see the softmax ``P`` of each
head's logits upsampled to image size.

The iteration, the discriminators, their optimiser and the weights ``model.method.lambda_adv_*``
are :class:`~uss_slam.train.methods.adversarial.AdversarialMethod`'s; the defaults
(``configs/model/method/adaptsegnet.yaml``) are the USS-SLAM paper's (``0.002`` / ``0.01``, ten
times AdaptSegNet's multi-level code).
"""

from __future__ import annotations

from typing import ClassVar

import torch.nn.functional as F
from torch import Tensor

from uss_slam.train.methods.adversarial import AdversarialMethod


class AdaptSegNet(AdversarialMethod):
    """The paper's method (``model/method=adaptsegnet``, the default)."""

    name: ClassVar[str] = "adaptsegnet"

    def target_map(self, logits: Tensor) -> Tensor:
        """The softmax ``P`` of target ``(N, C, H, W)`` logits."""
        return F.softmax(logits, dim=1)

    def source_map(self, log_probs: Tensor) -> Tensor:
        return log_probs.exp()
