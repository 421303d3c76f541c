"""Deterministic, headless RGB-D renderer of indoor scenes with people, chairs and monitors.

Public API::

    from uss_slam.synthetic import render_sequence, render_voc, PRESETS

- :func:`render_sequence` writes a TUM RGB-D sequence folder (plus ``labels/`` and
  ``intrinsics.yaml``) for one of :data:`PRESETS`, in the ``source`` or ``target`` style.
- :func:`render_voc` writes a PASCAL VOC 2012-layout segmentation set (``source`` style).

Pure NumPy / OpenCV (no torch, no OpenGL). Same arguments => byte-identical files.
"""

from .motion import PRESETS, Preset
from .output import OutputExistsError, SynthArgumentError
from .sequence import SequenceRenderer, render_sequence
from .styles import STYLES
from .voc import render_voc

__all__ = [
    "PRESETS",
    "STYLES",
    "OutputExistsError",
    "Preset",
    "SequenceRenderer",
    "SynthArgumentError",
    "render_sequence",
    "render_voc",
]
