"""The RGB normalisation every segmenter of this project is trained and exported with.

Torchvision's ImageNet statistics, per RGB channel on the 0..1 scale: the training transforms
apply ``(x / 255 - mean) / std``, the exported ONNX graph does the same inside itself and stores
both in its metadata.
"""

from __future__ import annotations

IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)
