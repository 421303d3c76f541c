"""Plain ``nn.Module`` components: the DeepLab-v2 and PSPNet segmenters, PatchGAN
discriminators, weights."""

from uss_slam.models.backbone import BACKBONES, ResNetBackbone, build_backbone
from uss_slam.models.deeplab import ASPPClassifier, DeepLabV2, SegmenterOutput, output_size
from uss_slam.models.discriminator import PatchDiscriminator
from uss_slam.models.pspnet import PSPNet
from uss_slam.models.weights import LoadReport, load_segmenter_weights

SEGMENTERS: tuple[type, ...] = (DeepLabV2, PSPNet)
"""The two-head segmenters (``net(images)`` -> ``aux``, ``main``; ``param_groups``)."""

__all__ = [
    "ASPPClassifier",
    "BACKBONES",
    "DeepLabV2",
    "LoadReport",
    "PSPNet",
    "PatchDiscriminator",
    "SEGMENTERS",
    "ResNetBackbone",
    "SegmenterOutput",
    "build_backbone",
    "load_segmenter_weights",
    "output_size",
]
