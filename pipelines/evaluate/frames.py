"""The labelled frames ``uss-eval`` scores: TUM RGB-D folders with ``labels/``, or the validation
set of a data config composed from the shipped configs."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uss_slam.core.cli import hydra_error_line
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.images import read_colour
from uss_slam.core.paths import distinct_folders, input_folder
from uss_slam.core.ranges import check_stride

from .models import MODEL_KINDS

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"


@dataclass(frozen=True)
class LabelledFrame:
    """``rgb`` (H, W, 3) uint8 RGB; ``labels`` (H, W) uint8 project class ids (255 ignore)."""

    name: str
    rgb: np.ndarray
    labels: np.ndarray


@dataclass
class FrameSource:
    """Labelled frames to evaluate: their count, a description and an iterator."""

    description: dict[str, Any]
    count: int
    frames: Callable[[], Iterator[LabelledFrame]]


def sequence_frames(roots: Sequence[Path], stride: int) -> FrameSource:
    """Every ``stride``-th colour frame of labelled frame folders: TUM RGB-D sequences with
    ``labels/``, or image folders with only ``rgb.txt``, ``rgb/`` and ``labels/`` (depth and
    ground truth are not needed). Lists and files are checked before any inference; a folder
    given twice is refused (``core.paths.distinct_folders``)."""
    from uss_slam.core.tum_io import is_file, read_tum_folder

    if stride < 1:
        raise UssSlamError(f"--stride: expected an integer >= 1, got {stride}")
    folders = []
    for root in roots:
        input_folder(root, "--sequence", "expected a TUM sequence folder with labels/")
    for root in distinct_folders(roots, "--sequence"):
        folder = read_tum_folder(root, depth=False, labels=True)
        check_stride(stride, len(folder.frames), "--stride", root)
        frames = folder.frames[::stride]
        for frame in frames:
            missing = folder.missing(frame)
            if missing is not None:
                raise missing
            if frame.labels is not None and not is_file(frame.labels):
                raise DataFormatError(
                    frame.labels, f"no labels for colour frame {frame.rgb.name} (expected a "
                    "uint8 class-id PNG of the same name in labels/)"
                )  # fmt: skip
        folders.append((root, frames))

    def frames() -> Iterator[LabelledFrame]:
        for root, files in folders:
            for frame in files:
                assert frame.labels is not None  # read with labels=True
                yield LabelledFrame(f"{root.name}/{frame.stamp:.6f}", *_read_pair(frame))

    description = {"source": "sequence", "roots": [str(r) for r in roots], "stride": stride}
    return FrameSource(description, sum(len(f) for _, f in folders), frames)


def _read_pair(frame: Any) -> tuple[np.ndarray, np.ndarray]:
    """The colour image (RGB) and the labels of ``frame``, checked (errors name the file)."""
    from uss_slam.slam_eval.sequence import read_labels

    bgr = read_colour(frame.rgb)
    labels = read_labels(frame.labels, bgr.shape[:2], frame.rgb.name)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), labels


def _instantiate_val(node: Any) -> Any:
    """``instantiate(data.val)``; a value its constructor rejects (``data.val.stride=0``) is
    one line naming ``data.val``, as in ``uss-train`` (Hydra wraps it with the target's name)."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    try:
        return instantiate(node)
    except InstantiationException as error:
        cause: BaseException | None = error
        while isinstance(cause, InstantiationException):
            cause = cause.__cause__
        if isinstance(cause, UssSlamError):
            raise cause from None
        if isinstance(cause, (ValueError, TypeError)):
            raise UssSlamError(f"data.val: {cause}") from None
        raise


def check_overrides(overrides: Sequence[str]) -> None:
    """Each of ``uss-eval``'s positional arguments after the model is a data-config override
    ``KEY=VALUE``: the first that is not is one line naming it (a second model file, a second
    value of an option that takes one)."""
    bad = [o for o in overrides if "=" not in o]
    if not bad:
        return
    hint = ""
    if Path(bad[0]).suffix.lower() in MODEL_KINDS:
        hint = "; two models are compared by uss-eval compare MODEL MODEL --sequence DIR"
    raise UssSlamError(
        f"{bad[0]!r}: expected a data-config override KEY=VALUE (e.g. data=real, "
        f"paths.data_dir=DIR, data.val.stride=1){hint}"
    )


def config_val_frames(overrides: Sequence[str]) -> FrameSource:
    """The validation set (``data.val``) of the data config composed from the shipped
    ``train`` config with ``overrides`` (e.g. ``data=real``, ``paths.data_dir=...``)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf

    from uss_slam.core.schema import check_targets

    check_overrides(overrides)
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
            cfg = compose("train", overrides=list(overrides))
    except Exception as error:  # an unknown key or option, bad override syntax: one line
        line = hydra_error_line(error)
        if line is None:
            raise
        raise UssSlamError(line) from None
    finally:
        GlobalHydra.instance().clear()
    node = OmegaConf.select(cfg, "data.val")
    if node is None:
        raise UssSlamError("the composed data config has no data.val (the validation set)")
    check_targets(cfg, ("data",))  # data.val.stride=abc: one line naming the key
    dataset = _instantiate_val(node)
    if not getattr(dataset, "labelled", False):
        raise UssSlamError("data.val has no labels: nothing to evaluate against")

    def frames() -> Iterator[LabelledFrame]:
        for k in range(len(dataset)):
            sample = dataset.load(k)
            rgb = sample["image"].permute(1, 2, 0).numpy()
            yield LabelledFrame(str(sample["name"]), rgb, sample["label"].numpy())

    description = {
        "source": "data.val",
        "overrides": list(overrides),
        "config": OmegaConf.to_container(node, resolve=True),
    }
    return FrameSource(description, len(dataset), frames)
