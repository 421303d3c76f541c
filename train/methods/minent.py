"""MinEnt: direct entropy minimisation on the target (Vu et al., ADVENT, CVPR 2019; its code's
``train_minent``).

One iteration: source forward with ``L_seg = λ_seg_aux·CE(aux) + λ_seg_main·CE(main)``, target
forward with ``L_ent = λ_ent_aux·E(aux) + λ_ent_main·E(main)``, one SGD step of the segmenter on
the sum. ``E`` is the mean over pixels of the entropy normalised by ``log C`` (ADVENT's
``entropy_loss``) of the softmax of the head's logits upsampled to image size. No discriminators
are built.

Weights. ADVENT's code and paper weight and normalise exactly as here (``entropy_loss`` = mean over
pixels of ``-sum_c P log2 P / log2 C``, against a cross-entropy that is a mean over the labelled
pixels; ``LAMBDA_ENT_MAIN`` 0.001, ``LAMBDA_ENT_AUX`` 0.0002). At those weights the entropy term is
a no-op at this project's budgets: its gradient norm on the segmenter's parameters is 0.008% of the
segmentation loss's at the demo's initialisation and 0.04–0.11% at trained demo checkpoints
(``studies/minent_gradient.py``, ``experiment=demo``). The defaults are 50× ADVENT's (``0.05``
main, ``0.01`` aux, the same 1 : 5), which puts that ratio at 0.42% at initialisation (0.38–0.48%
over 4 batches) and, the ratio being linear in the weights, 2–5.5% at those trained checkpoints, of
the order of the adversarial term's 2–8% in ``adaptsegnet`` at the paper's weights. ADVENT's
weights are one override away (``model.method.lambda_ent_main=0.001
model.method.lambda_ent_aux=0.0002``).
"""

from __future__ import annotations

from typing import ClassVar

from uss_slam.models.deeplab import SegmenterOutput
from uss_slam.train.losses import entropy_loss
from uss_slam.train.methods.base import (
    Method,
    StepValues,
    TargetLoss,
    TrainBatch,
    TrainingModule,
    check_weight,
    segmenter_step,
)


class MinEnt(Method):
    """``model/method=minent``: source segmentation + weighted target entropy.

    Args:
        lambda_ent_aux: weight of the aux head's target entropy (ADVENT's ``LAMBDA_ENT_AUX``
            0.0002 × 50; see the module docstring).
        lambda_ent_main: weight of the main head's target entropy (ADVENT's
            ``LAMBDA_ENT_MAIN`` 0.001 × 50).
    """

    name: ClassVar[str] = "minent"
    adapts: ClassVar[bool] = True

    def __init__(self, lambda_ent_aux: float = 0.01, lambda_ent_main: float = 0.05) -> None:
        super().__init__()
        self.lambda_ent_aux = check_weight("model.method.lambda_ent_aux", lambda_ent_aux)
        self.lambda_ent_main = check_weight("model.method.lambda_ent_main", lambda_ent_main)

    def settings(self) -> dict[str, float]:
        return {"lambda_ent_aux": self.lambda_ent_aux, "lambda_ent_main": self.lambda_ent_main}

    def training_step(self, module: TrainingModule, batch: TrainBatch) -> StepValues:
        images_trg = batch["target"]["image"]
        size = images_trg.shape[-2:]

        def entropy(pred: SegmenterOutput) -> TargetLoss:
            return TargetLoss(
                "loss_ent_trg",
                "loss_ent",
                entropy_loss(pred.aux, size),
                entropy_loss(pred.main, size),
                (self.lambda_ent_aux, self.lambda_ent_main),
            )

        return segmenter_step(module, batch["source"], images_trg, entropy).values

    def extra_repr(self) -> str:
        return (
            f"name={self.name!r}, lambda_ent_aux={self.lambda_ent_aux}, "
            f"lambda_ent_main={self.lambda_ent_main}"
        )
