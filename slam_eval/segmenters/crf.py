"""Dense-CRF refinement of a segmenter's class probabilities at SLAM time (torch-free).

A fully connected CRF with Gaussian edge potentials (Krähenbühl & Koltun, "Efficient Inference in
Fully Connected CRFs with Gaussian Edge Potentials", NIPS 2011), as DeepLab's post-process and the
CRF-RNN of the robust-semantic-mapping paper, run by pydensecrf2 (``pip install
'uss-slam[crf]'``): unary ``-log P`` from the softmax of the model's logits (clipped at 1e-5),
a smoothness kernel on pixel positions and an appearance (bilateral) kernel on positions and RGB,
both with Potts compatibility, mean-field inference.

Defaults (:class:`DenseCrf`) are the values of pydensecrf's documentation and example
(``addPairwiseGaussian(sxy=3, compat=3)``, ``addPairwiseBilateral(sxy=80, srgb=13,
compat=10)``, ``inference(5)``): smoothness ``θγ = 3`` px with weight 3, appearance
``θα = 80`` px and ``θβ = 13`` RGB levels with weight 10, 5 iterations. DeepLab tuned these per
data set by cross-validation (the DeepLab-v2 paper: smoothness fixed at ``w2 = 3, θγ = 3``,
appearance ``w1``, ``θα``, ``θβ`` searched, 10 iterations); every value is a key of
``segmenter.crf_params``.

Cost: linear in pixels and classes (permutohedral-lattice filtering), on the calling thread
(the segmenter's prefetch thread with ``segment=every_frame``); ``uss-slam`` reports it as the
``segmentation.crf`` row of the timing table.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from uss_slam.core.errors import UssSlamError

INSTALL_HINT = "pip install 'uss-slam[crf]' (pydensecrf2)"


def softmax(logits: np.ndarray) -> np.ndarray:
    """Softmax over axis 0 of ``(C, H, W)`` logits, float32."""
    shifted = np.exp(logits - logits.max(axis=0, keepdims=True))
    return (shifted / shifted.sum(axis=0, keepdims=True)).astype(np.float32, copy=False)


@dataclass(frozen=True)
class DenseCrf:
    """Parameters of the dense CRF and its inference (:meth:`refine`).

    Attributes:
        iterations: mean-field iterations.
        gaussian_sxy: smoothness kernel width ``θγ`` (pixels).
        gaussian_compat: smoothness kernel weight ``w2`` (Potts).
        bilateral_sxy: appearance kernel spatial width ``θα`` (pixels).
        bilateral_srgb: appearance kernel colour width ``θβ`` (RGB levels 0..255).
        bilateral_compat: appearance kernel weight ``w1`` (Potts).
    """

    iterations: int = 5
    gaussian_sxy: float = 3.0
    gaussian_compat: float = 3.0
    bilateral_sxy: float = 80.0
    bilateral_srgb: float = 13.0
    bilateral_compat: float = 10.0

    @classmethod
    def from_config(cls, params: Mapping[str, Any] | None, key: str) -> DenseCrf:
        """From a config mapping (missing keys take the defaults); a bad or unknown key is one
        :class:`UssSlamError` naming ``key.<name>``."""
        params = dict(params or {})
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(params) - set(known))
        if unknown:
            raise UssSlamError(f"{key}: unknown key {unknown[0]!r}; known: {', '.join(known)}")
        for name, value in params.items():
            if name == "iterations":
                ok = not isinstance(value, bool) and isinstance(value, int) and value >= 1
                expected = "a whole number >= 1"
            else:
                ok = not isinstance(value, bool) and isinstance(value, (int, float)) and value > 0
                expected = "a number > 0"
            if not ok:
                raise UssSlamError(f"{key}.{name} must be {expected}, got {value!r}")
        return cls(**params)

    def refine(self, rgb: np.ndarray, probs: np.ndarray) -> np.ndarray:
        """``(H, W, 3)`` uint8 RGB and ``(C, H, W)`` class probabilities -> the CRF's ``(C, H, W)``
        float32 marginals (each pixel's column sums to 1)."""
        densecrf, unary_from_softmax = _pydensecrf()
        classes, height, width = probs.shape
        if rgb.shape != (height, width, 3) or rgb.dtype != np.uint8:
            raise UssSlamError(
                f"dense CRF: expected an ({height}, {width}, 3) uint8 image for probabilities "
                f"of shape {probs.shape}, got {rgb.shape} {rgb.dtype}"
            )
        crf = densecrf.DenseCRF2D(width, height, classes)
        crf.setUnaryEnergy(np.ascontiguousarray(unary_from_softmax(probs)))
        crf.addPairwiseGaussian(sxy=self.gaussian_sxy, compat=self.gaussian_compat)
        crf.addPairwiseBilateral(
            sxy=self.bilateral_sxy,
            srgb=self.bilateral_srgb,
            rgbim=np.ascontiguousarray(rgb),
            compat=self.bilateral_compat,
        )
        marginals = np.asarray(crf.inference(self.iterations), dtype=np.float32)
        return marginals.reshape(classes, height, width)


def _pydensecrf() -> tuple[Any, Any]:
    """``pydensecrf.densecrf`` and ``unary_from_softmax``, or a one-line error saying how to
    install them."""
    try:
        import pydensecrf.densecrf as densecrf
        from pydensecrf.utils import unary_from_softmax
    except ImportError as error:
        raise UssSlamError(f"segmenter.crf=true needs pydensecrf: {INSTALL_HINT}") from error
    return densecrf, unary_from_softmax


def check_available() -> None:
    """Raise the install hint now (when the segmenter is built) rather than at the first frame."""
    _pydensecrf()
