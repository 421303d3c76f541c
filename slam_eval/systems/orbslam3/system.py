"""The real ORB-SLAM3 (RGB-D mode: tracking, local bundle adjustment, loop closing) as a second
SLAM system next to the harness: ``uss-slam system=orbslam3``.

It runs through the optional ``pyorbslam3`` bindings (GPL-3; ``pip install 'uss-slam[orbslam3]'``)
on the same TUM sequence reader, segmenters, scoring and report writer as the harness, so that
the numbers are comparable:

- **Settings**: an ORB-SLAM3 settings file (OpenCV ``%YAML:1.0``, ``File.version: "1.0"``, as
  ORB-SLAM3's RGB-D TUM examples) is written from the sequence's :class:`CameraIntrinsics` and
  ``system.*`` (:func:`~.settings.settings_yaml`); or ``system.settings_file`` names one of the user's.
  Either is checked here first (:func:`~.settings.check_settings`): ORB-SLAM3 ends the process on a missing
  or mistyped key.
- **Dynamic objects**: ORB-SLAM3 takes no masks, so the pixels of the region filters that find
  them in the frame alone (``filters=[...]``, by default ``semantic``: the segmenter's dynamic
  classes, dilated exactly as the harness's semantic filter, ``slam.filter_params.semantic``:
  ``dynamic_classes``, ``dilation``) are *blanked* in its input (:func:`~.masking.blank_dynamic`): the colour image is set to a
  flat grey (``system.blank_value``, default 128; ``system.blank_fill=inpaint`` fills it from
  the pixels around it instead) and the depth to 0 there. A flat region has no
  FAST corners inside; only its border can, where it meets the image. Grey rather than black:
  the border's contrast against a typical scene is smaller, so fewer corners appear on the
  silhouette (walking_xyz: 126 ORB keypoints per frame within 10 px of the mask with grey 128,
  156 with black; ``studies/orbslam3_blank_fill.py``). Corners centred inside the mask get
  no depth (no map point from a single frame); those just outside lie on what is behind the
  person, as the dilation reaches past its edge. ``segmenter=none`` blanks nothing.
- **Repeats**: ORB-SLAM3 runs its local mapping and loop closing in threads of its own and its
  results vary between runs of the same input; ``system.repeats`` (3) runs it that many times,
  each in a fresh Python process (ORB-SLAM3 keeps the first camera it saw in static members,
  and ends the process on some errors), and reports the ATE RMSE of the median run with the
  minimum and maximum. Every repeat's trajectory is kept (``repeats/trajectory_<i>.txt``); the
  median run's is ``trajectory.txt`` (for an even count, the lower of the two middle runs).
- **Untracked frames**: ORB-SLAM3's tracking state of every frame is counted (``OK``,
  ``RECENTLY_LOST``, ``LOST``, ``NOT_INITIALIZED`` ...); its trajectory
  (``SaveTrajectoryTUM``, after shutdown, so loop closures and bundle adjustment are in it) has no
  pose for lost frames: ``frames_without_pose`` counts them.
- **Vocabulary**: ``system.vocabulary``, a DBoW2 text vocabulary (``uss-vocab build`` makes a
  small one from frames; ORB-SLAM3's ``ORBvoc.txt`` works too). Nothing is downloaded.

Threads: besides the calling thread (tracking), ORB-SLAM3 starts its local-mapping and
loop-closing threads (and a global bundle adjustment thread after a loop closure); they cannot
be limited from here.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.errors import UssSlamError
from uss_slam.core.tum_io import StrPath

from ...filters.base import DynamicFilter
from ...filters.build import build_filters
from ...scoring.evaluation import EvalConfig, evaluate
from ...scoring.report import fmt
from ...scoring.run_folder import RunFolder
from ...segmenters.base import Segmenter
from ...sequence import MIN_STRIDED_FRAMES, TumSequence
from .config import INSTALL_HINT, OrbSlam3Config, check_system, check_vocabulary
from .masking import check_masks, compute_masks
from .repeats import RepeatResult, read_estimate
from .report import write_outputs
from .settings import SettingsInfo, check_settings, frame_rate, settings_yaml
from .thread import ThreadSpec, prepare, thread_pass
from .worker import Job, run_worker

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- the run


@dataclass(frozen=True)
class SequenceSpec:
    """How to open the sequence (``sequence.*`` of the config), for the worker processes too."""

    path: str
    camera: str | None = None
    max_diff: float = 0.02
    start: int = 0
    stride: int = 1
    max_frames: int | None = None

    def open(self, load_labels: bool = False) -> TumSequence:
        return TumSequence(
            self.path,
            camera=self.camera,
            max_diff=self.max_diff,
            load_labels=load_labels,
            start=self.start,
            stride=self.stride,
            max_frames=self.max_frames,
            min_strided_frames=MIN_STRIDED_FRAMES,
        )


def run_orbslam3(
    spec: SequenceSpec,
    segmenter: Segmenter,
    masks: Sequence[DynamicFilter],
    config: OrbSlam3Config,
    evaluation: EvalConfig,
    out_dir: StrPath,
    *,
    settings: dict[str, Any] | None = None,
    progress: bool = True,
    before_commit: Callable[[RunFolder], dict[str, Any]] | None = None,
    thread: ThreadSpec | None = None,
) -> dict[str, Any]:
    """Run ORB-SLAM3 ``config.repeats`` times on the sequence and write the outputs to
    ``out_dir``: ``trajectory.txt`` (median run), ``repeats/trajectory_<i>.txt`` and
    ``repeats/orbslam3_<i>.log``, ``orbslam3_settings.yaml``, ``metrics.json``, ``report.md``,
    ``trajectory.png``, ``ate.png``, ``repeats.png`` and the manifest ``run.json``. Returns the
    metrics dictionary.

    As the harness's runs (:mod:`~uss_slam.slam_eval.scoring.run_folder`), every file is staged
    until the last repeat is scored and replaces an earlier run's only then: a failed repeat,
    Ctrl-C or a full disk leaves the earlier run in ``out_dir`` as it was (a failed repeat's
    log is kept as ``orbslam3_failed.log``, which the error names). ``before_commit`` may write
    more files (Hydra's) into the folder and returns entries for the manifest."""
    if importlib.util.find_spec("pyorbslam3") is None:
        raise UssSlamError(
            f"system=orbslam3 needs the pyorbslam3 package (ORB-SLAM3 bindings, GPL-3): "
            f"{INSTALL_HINT}"
        )
    vocabulary = check_vocabulary(config.vocabulary)
    needs_labels = bool(getattr(segmenter, "needs_labels", False))
    sequence = spec.open(load_labels=needs_labels)
    out = Path(out_dir).absolute()
    fps = config.fps or frame_rate(sequence.stamps)
    with RunFolder.start(out) as folder, tempfile.TemporaryDirectory(prefix="uss-orbslam3-") as tmp:
        info, staged_settings = _settings_file(folder, out, sequence, config, fps)
        workdir = Path(tmp)
        masks_file = None
        mask_pass = None
        fill_dir = None
        thread_job, thread_figures = None, None
        if thread is not None:
            thread_job, thread_figures = prepare(
                thread, sequence, segmenter, workdir / "labels.npz"
            )
        elif getattr(segmenter, "name", "none") != "none":
            fill_dir = workdir / "filled" if config.blank_fill == "inpaint" else None
            mask_pass = compute_masks(sequence, segmenter, masks, progress, fill_dir)
            masks_file = workdir / "masks.npy"
            np.save(masks_file, mask_pass.packed)
        job = Job(
            sequence=asdict(spec),
            vocabulary=str(vocabulary.resolve()),
            settings=str(staged_settings.resolve()),
            depth_factor=info.depth_factor,
            rgb=info.rgb,
            masks=None if masks_file is None else str(masks_file),
            blank_value=config.blank_value,
            filled=None if fill_dir is None else str(fill_dir),
            realtime=config.realtime,
            trajectory="",
            result="",
            thread=thread_job,
        )
        results = [
            _repeat(folder, out, job, workdir, i, sequence, evaluation, config.repeats)
            for i in range(config.repeats)
        ]
        if thread_figures is not None:
            mask_pass = thread_pass(thread_figures, results, sequence.image_size)
        data = write_outputs(
            folder, out, sequence, segmenter, masks, config, evaluation, info, fps,
            vocabulary, mask_pass, results, settings, thread_figures,
        )  # fmt: skip
        extra = before_commit(folder) if before_commit is not None else {}
        folder.commit(system="orbslam3", sequence=str(sequence.path), **extra)
    (out / FAILED_LOG).unlink(missing_ok=True)  # the run that failed before is redone
    return data


def _settings_file(
    folder: RunFolder, out: Path, sequence: TumSequence, config: OrbSlam3Config, fps: int
) -> tuple[SettingsInfo, Path]:
    """The checked settings file (the user's ``system.settings_file``, else one written from
    the sequence's camera into ``out``, staged) and the path ORB-SLAM3 reads it from."""
    if config.settings_file:
        info = check_settings(Path(os.path.expanduser(config.settings_file)), sequence.image_size)
        return info, info.path
    final = out / "orbslam3_settings.yaml"
    with folder.writing(final) as staged:
        staged.write_text(settings_yaml(sequence.camera, config, fps), encoding="utf-8")
    staged_settings = folder.current(final)
    return replace(
        check_settings(staged_settings, sequence.image_size), path=final
    ), staged_settings


def _repeat(
    folder: RunFolder,
    out: Path,
    job: Job,
    workdir: Path,
    i: int,
    sequence: TumSequence,
    evaluation: EvalConfig,
    repeats: int,
) -> RepeatResult:
    """Repeat ``i`` of ``repeats``: ``job`` in a fresh worker process, its trajectory and log
    placed under ``out/repeats/`` (staged), scored; a failed repeat's log is kept."""
    final_trajectory = out / "repeats" / f"trajectory_{i}.txt"
    with (
        folder.placing(final_trajectory) as trajectory_path,
        folder.placing(out / "repeats" / f"orbslam3_{i}.log") as log_path,
    ):
        mine = replace(
            job, trajectory=str(trajectory_path), result=str(workdir / f"result_{i}.json")
        )
        try:
            raw = run_worker(mine, log_path, workdir, i)
        except UssSlamError:
            keep_failed_log(log_path, out / FAILED_LOG)
            raise
    trajectory = read_estimate(trajectory_path)
    result = RepeatResult(
        i, final_trajectory, trajectory, raw["states"], raw["track_s"], raw["load_s"],
        thread=raw.get("thread"),
    )  # fmt: skip
    result.evaluation = evaluate(trajectory, sequence.groundtruth, evaluation)
    log.info(
        "orbslam3 repeat %d/%d: ATE RMSE %s m, %d/%d frames OK, %.1f frames/s",
        i + 1,
        repeats,
        "n/a" if result.ate_rmse is None else f"{result.ate_rmse:.4f}",
        result.state_counts.get("OK", 0),
        len(sequence),
        len(sequence) / result.track_s if result.track_s > 0 else 0.0,
    )
    return result


FAILED_LOG = "orbslam3_failed.log"
"""In ``out_dir``: the log of the repeat that stopped the last run (its outputs are discarded)."""


def keep_failed_log(staged: Path, kept: Path) -> None:
    """Copy a failed repeat's log out of the staging folder that is about to go."""
    # the error names the log; a log that could not be kept is no second error
    with contextlib.suppress(OSError):
        shutil.copyfile(staged, kept)


# --------------------------------------------------------------------------- Hydra glue


def run_from_config(
    cfg: Any,
    out_dir: StrPath,
    before_commit: Callable[[RunFolder], dict[str, Any]] | None = None,
    overrides: Sequence[str] = (),
) -> dict[str, Any]:
    """``uss-slam system=orbslam3``: build everything from the composed config and run
    (``before_commit``: as :func:`run_orbslam3`'s; ``overrides``: the command line's)."""
    import hydra
    from omegaconf import OmegaConf

    if cfg.get("compare") is not None:
        raise UssSlamError(
            "system=orbslam3 runs one configuration per call; compare= is the harness's "
            "(run once with segmenter=none and once with segmenter=labels instead)"
        )
    segment = str(cfg.get("segment", "every_frame"))
    if segment == "keyframes":
        raise UssSlamError(
            "system=orbslam3 segments every frame or, with segment=thread, one frame per "
            "segmenter.latency_s (its keyframe choice is internal); segment=keyframes applies "
            "to the harness only"
        )
    config = check_system(OmegaConf.to_container(cfg.system, resolve=True) or {})
    seq = cfg.sequence
    spec = SequenceSpec(
        path=str(seq.path),
        camera=None if seq.camera is None else str(seq.camera),
        max_diff=float(seq.max_diff),
        start=int(seq.start),
        stride=int(seq.stride),
        max_frames=None if seq.max_frames is None else int(seq.max_frames),
    )
    masks = _mask_filters(cfg)
    ev = OmegaConf.to_container(cfg.eval, resolve=True) or {}
    try:
        evaluation = EvalConfig(**ev)
    except TypeError as err:
        raise UssSlamError(f"eval: {err}") from None
    segmenter: Segmenter = hydra.utils.instantiate(cfg.segmenter)
    line = empty_filters_refused(cfg, overrides, getattr(segmenter, "name", "none"))
    if line is not None:
        raise UssSlamError(line)
    if list(cfg.get("filters") or []) and getattr(segmenter, "name", "none") == "none":
        raise UssSlamError(
            f"system=orbslam3: filters={list(cfg.filters)} blank what a segmenter finds; set "
            "segmenter=labels or an exported model (segmenter=none blanks nothing)"
        )
    thread = _thread_spec(cfg, segmenter) if segment == "thread" else None
    data = run_orbslam3(
        spec,
        segmenter,
        masks,
        config,
        evaluation,
        out_dir,
        settings=OmegaConf.to_container(cfg, resolve=True),
        progress=bool(cfg.get("progress", True)),
        before_commit=before_commit,
        thread=thread,
    )
    rep = data["ate_rmse_repeats"]
    log.info(
        "orbslam3: ATE RMSE median %s m (min %s, max %s) over %d repeats, %d/%d frames OK -> %s",
        fmt(rep["median"]),
        fmt(rep["min"]),
        fmt(rep["max"]),
        len(data["repeats"]),
        data["frames_tracked"],
        data["frames"],
        out_dir,
    )
    return data


def empty_filters_refused(cfg: Any, overrides: Sequence[str], segmenter: str) -> str | None:
    """One line when the command line sets ``filters=[]`` with a segmenter: for the harness
    that is the unfiltered run, but ORB-SLAM3 would blank its default filter's pixels
    (:data:`DEFAULT_MASK`) all the same; the unfiltered ORB-SLAM3 run is ``segmenter=none``."""
    given = {o.lstrip("+~").split("=", 1)[0] for o in overrides}
    if "filters" not in given or list(cfg.get("filters") or []):
        return None
    if segmenter == "none":
        return None
    return (
        "system=orbslam3: filters=[] would still blank the semantic filter's pixels (ORB-SLAM3's "
        "default with a segmenter); for a run without masks set segmenter=none, to blank "
        "filters name them (filters=[semantic])"
    )


def _mask_filters(cfg: Any) -> list[DynamicFilter]:
    """The filters whose pixels are blanked in ORB-SLAM3's input: ``filters=[...]`` (each must
    find its pixels in the frame alone), by default the semantic filter's node."""
    from omegaconf import OmegaConf

    names = [str(n) for n in (cfg.get("filters") or [])]
    params = OmegaConf.to_container(cfg.slam.filter_params, resolve=True) or {}
    masks = build_filters(names or [DEFAULT_MASK], params)
    check_masks(masks)
    return masks


def _thread_spec(cfg: Any, segmenter: Segmenter) -> ThreadSpec:
    """``segment=thread`` with ORB-SLAM3 (:mod:`.thread`): the segmenter must simulate its
    latency on the camera clock (``segmenter=labels segmenter.latency_s=L``, ``wait`` false)."""
    from omegaconf import OmegaConf

    latency = getattr(segmenter, "simulated_latency_s", None)
    if latency is None:
        raise UssSlamError(
            "system=orbslam3 segment=thread: the segmenter must simulate its latency on the "
            "camera clock (segmenter=labels segmenter.latency_s=<s>, segmenter.wait=false); "
            f"segmenter {getattr(segmenter, 'name', '?')!r} does not"
        )
    names = [str(n) for n in (cfg.get("filters") or [])] or [DEFAULT_MASK]
    params = OmegaConf.to_container(cfg.slam.filter_params, resolve=True) or {}
    return ThreadSpec(float(latency), names, params)


DEFAULT_MASK = "semantic"
"""The filter whose pixels ORB-SLAM3's input loses when ``filters`` names none."""
