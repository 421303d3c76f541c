"""Semantic Boundaries Dataset (SBD, Hariharan et al. 2011): the ``benchmark_RELEASE`` tree.

Layout (as unpacked from ``benchmark.tgz``)::

    benchmark_RELEASE/dataset/
        img/<id>.jpg        images (VOC 2011 photos)
        cls/<id>.mat        class labels: struct GTcls {Boundaries, Segmentation, CategoriesPresent}
        inst/<id>.mat       instance labels (not used here)
        train.txt, val.txt  id lists (8,498 / 2,857 ids); optionally train_noval.txt

``GTcls.Segmentation`` is an ``(H, W)`` array of VOC class indices (0 background .. 20
tvmonitor), read with :func:`scipy.io.loadmat` and remapped to project classes with the VOC
table (``classes.voc_lut()``). SBD's ``train`` overlaps VOC 2012 ``val``; use ``train_noval``
(if you have that list) or the selection's ``exclude_voc_val`` rule.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io

from uss_slam.core.errors import DataFormatError
from uss_slam.datasets.base import map_label
from uss_slam.datasets.voc import IdListSegmentation

GTCLS_FIELDS = ("Boundaries", "Segmentation", "CategoriesPresent")


def find_sbd_root(root: str | Path) -> Path:
    """Accept ``benchmark_RELEASE/dataset`` itself, ``benchmark_RELEASE``, or its parent."""
    root = Path(root)
    for candidate in (root, root / "dataset", root / "benchmark_RELEASE" / "dataset"):
        if (candidate / "cls").is_dir() and (candidate / "img").is_dir():
            return candidate
    if not root.exists():
        raise DataFormatError(root, "SBD root not found")
    raise DataFormatError(
        root,
        "not an SBD tree: expected img/ and cls/ under it, under dataset/ or under "
        "benchmark_RELEASE/dataset/",
    )


def read_gtcls_segmentation(path: Path) -> np.ndarray:
    """``GTcls.Segmentation`` of an SBD ``cls/*.mat`` file: ``(H, W)`` VOC class indices.

    Raises :class:`DataFormatError` naming the file when it is no MAT file, holds no ``GTcls``
    struct with a ``Segmentation`` field, or the field is not a 2-D array of integers 0..255.
    """
    try:
        mat = scipy.io.loadmat(path, variable_names=["GTcls"])
    except FileNotFoundError:
        raise DataFormatError(path, "label file not found") from None
    except Exception as error:  # noqa: BLE001 - scipy raises many types for damaged files
        raise DataFormatError(
            path, f"cannot read MAT file ({type(error).__name__}: {error})"
        ) from error
    if "GTcls" not in mat:
        raise DataFormatError(path, "no GTcls variable (expected SBD's cls/*.mat struct GTcls)")
    gt = mat["GTcls"]
    names = gt.dtype.names or ()
    if "Segmentation" not in names or gt.size != 1:
        raise DataFormatError(
            path, f"GTcls must be a struct with fields {', '.join(GTCLS_FIELDS)}; got {names}"
        )
    segmentation = np.asarray(gt["Segmentation"].flat[0])
    if segmentation.ndim != 2 or not np.issubdtype(segmentation.dtype, np.integer):
        raise DataFormatError(
            path,
            f"GTcls.Segmentation must be a 2-D integer array of class indices, got "
            f"{segmentation.dtype} {segmentation.shape}",
        )
    if segmentation.size and (segmentation.min() < 0 or segmentation.max() > 255):
        raise DataFormatError(
            path,
            f"GTcls.Segmentation values must be VOC class indices, got "
            f"{segmentation.min()}..{segmentation.max()}",
        )
    return segmentation.astype(np.uint8)


class SBDSegmentation(IdListSegmentation):
    """SBD class segmentation with project classes.

    Args:
        root: ``benchmark_RELEASE/dataset`` (or ``benchmark_RELEASE``, or the folder holding it).
        split: id list ``<split>.txt`` in the dataset folder: ``train``, ``val`` or
            ``train_noval`` (not shipped with SBD; the common list of train ids outside VOC
            2012 val).
        transform: joint v2 transform (see :mod:`uss_slam.datasets.transforms`).
        on_error: ``raise`` or ``skip`` an image without label (or the reverse), as
            :class:`~uss_slam.datasets.voc.VOCSegmentation`.

    Samples: ``image (3, H, W)`` float32, ``label (H, W)`` int64, ``name`` = image id.
    """

    kind = "SBD"
    image_dir, image_suffix = "img", ".jpg"
    label_dir, label_suffix = "cls", ".mat"
    find_root = staticmethod(find_sbd_root)

    def split_list(self, split: str) -> Path:
        return self.root / f"{split}.txt"

    def missing_hint(self, split: str) -> str:
        if split != "train_noval":
            return ""
        return (
            " (train_noval.txt is not part of SBD; use split=train with the selection's "
            "exclude_voc_val rule instead)"
        )

    def read_label(self, index: int) -> np.ndarray:
        path = self.items[index].label
        assert path is not None
        return map_label(path, read_gtcls_segmentation(path), self.lut)
