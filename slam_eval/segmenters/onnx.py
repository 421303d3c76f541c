"""The runtime of exported segmenters: :class:`OnnxSegmenter` runs an ``uss-export`` model with
onnxruntime (never torch).

``uss-slam segmenter=onnx segmenter.path=exports/x.onnx [segmenter.threads=1]
[segmenter.providers=cpu|cuda|auto] [segmenter.threshold=0.3] [segmenter.crf=true]``
(``configs/segmenter/onnx.yaml``).

``threshold`` (default ``None``: the model's own ``labels``, the argmax) labels a pixel with a
dynamic class when that class's softmax probability, from the model's ``logits``, is at least
``threshold``; a pixel whose argmax is a dynamic class below ``threshold`` gets its most probable
static class. Below 0.5 it trades static pixels for more of the people a model half sees.

``crf`` (default ``False``: unchanged) refines the softmax of the model's ``logits`` with a dense
CRF (:mod:`.crf`, parameters ``crf_params``) before the labels are taken (argmax, or
``threshold`` on the refined probabilities); its time per call is reported by
:meth:`OnnxSegmenter.stage_times` (the ``segmentation.crf`` row of the run's timing table).

The model must follow the contract of :mod:`uss_slam.core.onnx_contract` (``exports/README.md``):
input ``image`` uint8 RGB NHWC with dynamic batch / height / width, output ``labels`` uint8
``(N, H, W)``, and our ``metadata_props``. Anything else is refused when the segmenter is built,
with the file and what is missing. Its outputs are held to its metadata where it runs: the
``logits`` must have one channel per class of ``uss_slam.class_names`` (checked when the shape
declares it, and on the first frame), and every label must be one of those classes' ids (the
largest label of every frame; :func:`~uss_slam.core.onnx_contract.check_label_ids`). The
model's class names are mapped to the project's class ids by name, so a model trained with
another class order still yields project ids.

Thread safety: the pipeline calls :meth:`OnnxSegmenter.infer` from its prefetch threads at once
(``segment=every_frame``, ``slam.workers`` threads). ``onnxruntime.InferenceSession.run`` is
thread-safe (one session, concurrent ``run`` calls are supported by onnxruntime), the CRF is
built per call and the stage times are kept per thread, so one segmenter is shared by all
threads. Each call uses up to ``threads`` intra-op threads: with ``slam.workers`` concurrent
calls, ``threads`` x ``slam.workers`` should not exceed the cores.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping, Sequence
from os import PathLike
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import onnxruntime as ort

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.cli import warning
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.onnx_contract import (
    INPUT_NAME,
    KEY_DYNAMIC_CLASSES,
    OUTPUT_LABELS,
    OUTPUT_LOGITS,
    SegmenterMetadata,
    check_label_ids,
    check_logit_channels,
)
from uss_slam.core.paths import input_file
from uss_slam.core.ranges import MAX_THREADS, THREADS

from .base import ImageSegmenter
from .crf import DenseCrf, check_available, softmax

PROVIDER_ALIASES = {"cpu": "CPUExecutionProvider", "cuda": "CUDAExecutionProvider"}
"""Short names accepted for ``providers``, besides onnxruntime's own provider names."""


def resolve_providers(providers: str | Sequence[str] | None) -> list[str]:
    """onnxruntime execution providers for ``providers``.

    ``None`` / ``"cpu"``: CPU only (the default). ``"cuda"``: CUDA, then CPU for operators CUDA
    lacks; an error when this onnxruntime build has no CUDA. ``"auto"``: CUDA when available,
    else CPU. A list: those providers (short names or onnxruntime names), in order of preference;
    each must be available.
    """
    available = ort.get_available_providers()
    if providers is None:
        return ["CPUExecutionProvider"]
    if isinstance(providers, str):
        if providers == "auto":
            if "CUDAExecutionProvider" in available:
                return ["CUDAExecutionProvider", "CPUExecutionProvider"]
            return ["CPUExecutionProvider"]
        providers = [providers]
    names = [PROVIDER_ALIASES.get(str(p).lower(), str(p)) for p in providers]
    if not names:
        raise UssSlamError("segmenter.providers is empty; use cpu, cuda, auto or provider names")
    missing = [n for n in names if n not in available]
    if missing:
        given = providers[0] if len(providers) == 1 else "[" + ",".join(map(str, providers)) + "]"
        raise UssSlamError(
            f"segmenter.providers={given}: execution provider(s) {', '.join(missing)} not "
            f"available in this onnxruntime build (available: {', '.join(available)}); expected "
            "cpu or auto"
        )
    if names == ["CUDAExecutionProvider"]:
        names.append("CPUExecutionProvider")
    return names


class OnnxSegmenter(ImageSegmenter):
    """An exported segmenter run by onnxruntime: ``infer(rgb) -> (H, W) uint8`` project class ids.

    ``path``: the ``.onnx`` file. ``threads``: intra-op threads per call (``None``: onnxruntime's
    default, all cores). ``providers``: ``"cpu"`` (default), ``"cuda"``, ``"auto"`` or a list of
    provider names (see :func:`resolve_providers`). ``threshold``, ``crf`` and ``crf_params``: see
    the module docstring (``crf_params`` keys: :class:`~.crf.DenseCrf`, missing ones default).

    Attributes: ``metadata`` (:class:`~uss_slam.core.onnx_contract.SegmenterMetadata`),
    ``providers`` (the session's providers), ``dynamic_classes`` (the model's, by name).
    """

    needs_labels = False

    def __init__(
        self,
        path: str | PathLike[str],
        threads: Annotated[int | None, THREADS] = None,
        providers: str | Sequence[str] | None = "cpu",
        threshold: float | None = None,
        crf: bool = False,
        crf_params: Mapping[str, Any] | None = None,
    ) -> None:
        self.path = Path(path)
        input_file(self.path, "segmenter.path", "expected an ONNX model written by uss-export")
        _check_settings(threads, threshold, crf)
        self.threshold = None if threshold is None else float(threshold)
        self.crf = DenseCrf.from_config(crf_params, "segmenter.crf_params") if crf else None
        if self.crf is not None:
            check_available()
        self._local = threading.local()
        session = self._open(threads, providers)
        self.metadata = SegmenterMetadata.from_props(
            session.get_modelmeta().custom_metadata_map, self.path
        )
        self._check_io(session)
        # The logits' channels checked against the class list: now when the graph declares
        # them, else on the first frame (``_first_frame``).
        self._first_frame = self._check_logits(session, crf)
        self.session = session
        self.providers = session.get_providers()
        self.threads = None if threads is None else int(threads)
        self.name = f"onnx:{self.path.name}"
        self.dynamic_classes = self.metadata.dynamic_classes
        self._map_classes()

    def _open(
        self, threads: int | None, providers: str | Sequence[str] | None
    ) -> ort.InferenceSession:
        """The onnxruntime session of :attr:`path`; a file it cannot load is one line."""
        options = ort.SessionOptions()
        if threads is not None:
            options.intra_op_num_threads = int(threads)
        options.inter_op_num_threads = 1
        # No busy-waiting of idle pool threads: the SLAM front end shares the cores.
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        options.log_severity_level = 3
        resolved = resolve_providers(providers)
        try:
            return ort.InferenceSession(str(self.path), options, providers=resolved)
        except Exception as error:  # onnxruntime raises its own exception types
            if _is_torch_checkpoint(self.path):
                raise DataFormatError(
                    self.path,
                    "a PyTorch checkpoint, not an ONNX model; export it first: uss-export "
                    f"ckpt_path={self.path}",
                ) from None
            raise DataFormatError(self.path, _unloadable(self.path, error)) from None

    def _check_logits(self, session: ort.InferenceSession, crf: bool) -> bool:
        """Whether the model has the logits output (its channels checked against the class
        list when the graph declares them); ``threshold`` and ``crf`` need it."""
        has_logits = OUTPUT_LOGITS in {o.name for o in session.get_outputs()}
        if has_logits:
            logits = next(o for o in session.get_outputs() if o.name == OUTPUT_LOGITS)
            shape = list(logits.shape)
            channels = shape[1] if len(shape) == 4 and isinstance(shape[1], int) else None
            check_logit_channels(self.path, self.metadata.class_names, channels)
        for key, used in (("threshold", self.threshold is not None), ("crf", crf)):
            if used and not has_logits:
                raise DataFormatError(
                    self.path, f"segmenter.{key} needs the model's {OUTPUT_LOGITS!r} output"
                )
        return has_logits

    def _map_classes(self) -> None:
        """The model's classes as project class ids (:attr:`_lut`, None when they coincide)
        and the model channels of its dynamic classes (for ``threshold``)."""
        unknown = [n for n in self.metadata.class_names if n not in CLASS_NAMES]
        if unknown:
            raise DataFormatError(
                self.path,
                f"class names {unknown} of the model are not project classes "
                f"({', '.join(CLASS_NAMES)})",
            )
        ids = [CLASS_NAMES.index(n) for n in self.metadata.class_names]
        # Model class index -> project class id; None when they coincide.
        self._lut: np.ndarray | None = None
        if ids != list(range(len(ids))):
            lut = np.zeros(256, np.uint8)
            lut[: len(ids)] = ids
            self._lut = lut
        names = list(self.metadata.class_names)
        self._dynamic_channels = np.array(
            [names.index(n) for n in self.dynamic_classes if n in names], np.int64
        )
        if self.threshold is not None and not self.dynamic_classes:
            warning(
                f"{self.path}: metadata {KEY_DYNAMIC_CLASSES} is empty (the model names no "
                f"dynamic class), so segmenter.threshold={self.threshold:g} changes no label"
            )

    def _check_io(self, session: ort.InferenceSession) -> None:
        inputs = session.get_inputs()
        if len(inputs) != 1 or inputs[0].name != INPUT_NAME:
            names = [i.name for i in inputs]
            raise DataFormatError(
                self.path, f"expected one input named {INPUT_NAME!r}, the model has {names}"
            )
        image = inputs[0]
        shape = list(image.shape)
        if image.type != "tensor(uint8)" or len(shape) != 4 or shape[3] != 3:
            raise DataFormatError(
                self.path,
                f"input {INPUT_NAME!r} is {image.type} of shape {shape}; expected "
                "tensor(uint8) of shape (N, H, W, 3) (RGB, NHWC)",
            )
        fixed = [d for d in shape[1:3] if isinstance(d, int)]
        if fixed:
            raise DataFormatError(
                self.path,
                f"input {INPUT_NAME!r} has a fixed height/width {shape[1:3]}; the contract "
                "needs dynamic H and W (re-export with uss-export)",
            )
        outputs = {o.name: o for o in session.get_outputs()}
        labels = outputs.get(OUTPUT_LABELS)
        if labels is None or labels.type != "tensor(uint8)" or len(labels.shape) != 3:
            found = {n: (o.type, list(o.shape)) for n, o in outputs.items()}
            raise DataFormatError(
                self.path,
                f"expected an output {OUTPUT_LABELS!r} tensor(uint8) of shape (N, H, W); "
                f"the model's outputs are {found}",
            )

    def infer(self, rgb: np.ndarray) -> np.ndarray:
        """``(H, W, 3)`` uint8 RGB -> ``(H, W)`` uint8 project class ids (thread-safe)."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise UssSlamError(
                f"{self.name}: expected an (H, W, 3) uint8 RGB image, got shape {rgb.shape} "
                f"and dtype {rgb.dtype}"
            )
        batch = np.ascontiguousarray(rgb)[None]
        if self.threshold is None and self.crf is None and self._first_frame:
            # once: the logits' channels against the class list (then the labels alone)
            labels, logits = self.session.run([OUTPUT_LABELS, OUTPUT_LOGITS], {INPUT_NAME: batch})
            self._checked_logits(logits[0])
            self._first_frame = False
            labels = labels[0]
        elif self.threshold is None and self.crf is None:
            (labels,) = self.session.run([OUTPUT_LABELS], {INPUT_NAME: batch})
            labels = labels[0]
        else:
            (logits,) = self.session.run([OUTPUT_LOGITS], {INPUT_NAME: batch})
            prob = softmax(self._checked_logits(logits[0]))
            if self.crf is not None:
                wall, cpu = time.perf_counter(), time.thread_time()
                prob = self.crf.refine(rgb, prob)
                self._local.times = {"crf": (time.perf_counter() - wall, time.thread_time() - cpu)}
            if self.threshold is None:
                labels = prob.argmax(axis=0).astype(np.uint8)
            else:
                labels = self._thresholded(prob)
        if labels.shape != rgb.shape[:2]:
            raise DataFormatError(
                self.path,
                f"output {OUTPUT_LABELS!r} has shape {labels.shape} for an input of "
                f"{rgb.shape[:2]}; the contract says labels at the input size",
            )
        check_label_ids(self.path, self.metadata.class_names, labels)
        if self._lut is not None:
            labels = self._lut[labels]
        return labels

    def stage_times(self) -> dict[str, tuple[float, float]]:
        """Wall and CPU seconds of the named stages of the calling thread's last :meth:`infer`
        (``{"crf": (wall, cpu)}`` with ``crf``, else empty), forgotten once read."""
        times = getattr(self._local, "times", {})
        self._local.times = {}
        return times

    def _checked_logits(self, logits: np.ndarray) -> np.ndarray:
        if logits.ndim != 3:
            raise DataFormatError(
                self.path,
                f"output {OUTPUT_LOGITS!r} has shape {logits.shape[:]} per image; expected "
                f"({len(self.metadata.class_names)}, H, W)",
            )
        check_logit_channels(self.path, self.metadata.class_names, logits.shape[0])
        return logits

    def _thresholded(self, prob: np.ndarray) -> np.ndarray:
        """``(C, H, W)`` class probabilities -> ``(H, W)`` uint8 model class indices with the
        dynamic classes decided by ``threshold`` on their probability."""
        dyn = self._dynamic_channels
        static = prob.copy()
        static[dyn] = -1.0
        labels = static.argmax(axis=0).astype(np.uint8)
        if dyn.size:
            dyn_prob = prob[dyn]
            best = dyn_prob.argmax(axis=0)
            chosen = np.take_along_axis(dyn_prob, best[None], axis=0)[0] >= self.threshold
            labels[chosen] = dyn[best[chosen]].astype(np.uint8)
        return labels

    def __repr__(self) -> str:
        return (
            f"OnnxSegmenter({str(self.path)!r}, threads={self.threads}, "
            f"providers={self.providers}, threshold={self.threshold}, crf={self.crf}, "
            f"classes={list(self.metadata.class_names)})"
        )


def _is_torch_checkpoint(path: Path) -> bool:
    """Whether ``path`` is a file ``torch.save`` wrote (a zip archive holding ``data.pkl``)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            return any(name.endswith("data.pkl") for name in archive.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


def _check_settings(threads: object, threshold: object, crf: object) -> None:
    """``segmenter.threads``, ``.threshold`` and ``.crf``: one line for a bad value."""
    if threads is not None and (
        isinstance(threads, bool) or not isinstance(threads, int) or threads < 1
        or threads > MAX_THREADS
    ):  # fmt: skip
        raise UssSlamError(
            f"segmenter.threads must be a whole number in 1..{MAX_THREADS} (4 per CPU) or "
            f"null, got {threads!r}"
        )
    if threshold is not None and (
        isinstance(threshold, bool)
        or not isinstance(threshold, int | float)
        or not 0.0 < threshold < 1.0
    ):
        raise UssSlamError(
            f"segmenter.threshold must be a probability in (0, 1) or null, got {threshold!r}"
        )
    if not isinstance(crf, bool):
        raise UssSlamError(f"segmenter.crf must be true or false, got {crf!r}")


_ONNXRUNTIME_FAILURES = {
    "No graph was found": "holds no ONNX graph",
    "Protobuf parsing failed": "is not an ONNX protobuf (truncated, or another format)",
}
"""onnxruntime's texts for a file that is not a whole ONNX model -> what the line says."""


def _unloadable(path: Path, error: BaseException) -> str:
    """What the line says of a model file onnxruntime cannot load: an empty file, one that is
    not a whole ONNX model, else onnxruntime's own first line (an opset or operator it lacks)."""
    expected = "expected an ONNX model written by uss-export"
    if path.is_file() and path.stat().st_size == 0:
        return f"is empty (0 bytes); {expected}"
    text = str(error).strip()
    for found, says in _ONNXRUNTIME_FAILURES.items():
        if found in text:
            return f"{says}; {expected}"
    first = text.splitlines()[0] if text else repr(error)
    return f"onnxruntime cannot load it as an ONNX model: {first}"
