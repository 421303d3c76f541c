"""What every driver (``uss-demo``, ``uss-experiments``) does with a training run and a SLAM run:
choose a run's checkpoint by a named policy, compose and run a training, describe a SLAM run as
one typed value (:class:`SlamJob`, with its :class:`Segmenter`) and compose and run it.

The drivers are siblings that never import each other; both import this module::

    metrics = run_training(run_dir, ["experiment=demo", "model/method=adaptsegnet"])
    ckpt = select_checkpoint(run_dir)                      # policy "last"
    job = SlamJob(sequence, Segmenter.onnx(model), filters=("semantic",))
    data = run_slam(job, out_dir / "slam" / "adapted", progress=False)

A :class:`SlamJob` turns into ``uss-slam`` overrides in one place (:meth:`SlamJob.overrides`);
the experiments' job plans carry it as JSON (:meth:`SlamJob.to_json` / :meth:`SlamJob.from_json`)
because their jobs run in other processes.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import json
import re
import shutil
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from uss_slam.core.errors import UssSlamError
from uss_slam.core.paths import path_override
from uss_slam.slam_eval.variants import Variant

if TYPE_CHECKING:
    from omegaconf import DictConfig

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
"""The package's Hydra config tree (``configs/``)."""


# ------------------------------------------------------------------------- checkpoints

CheckpointPolicy = Callable[[Path], Path]
"""A checkpoint selection policy: a training run's folder -> the checkpoint to export."""


def best_target_val(run_dir: Path) -> Path:
    """The checkpoint with the best target-validation ``val/mIoU`` (``best_*.ckpt``, written by
    the checkpoint callback; ``last.ckpt`` if there is none). Uses target labels."""
    folder = run_dir / "checkpoints"
    best = sorted(folder.glob("best_*.ckpt"))
    if best:
        return best[-1]
    last = folder / "last.ckpt"
    if last.is_file():
        return last
    raise UssSlamError(f"{folder}: no checkpoint (best_*.ckpt or last.ckpt) after training")


def last(run_dir: Path) -> Path:
    """The last checkpoint (``last.ckpt``): the model at the run's fixed budget. Uses no
    target labels, as an unsupervised method must not."""
    path = run_dir / "checkpoints" / "last.ckpt"
    if not path.is_file():
        raise UssSlamError(f"{path.parent}: no last.ckpt after training")
    return path


CHECKPOINT_POLICIES: dict[str, CheckpointPolicy] = {
    "last": last,
    "best_target_val": best_target_val,
}
"""Policies by name. A new policy is one function ``(run_dir) -> checkpoint`` added here (and
to :data:`USES_TARGET_LABELS` when it reads target labels)."""

USES_TARGET_LABELS = frozenset({"best_target_val"})
"""Policies that choose with target labels: tables mark their rows as such."""

DEFAULT_POLICY = "last"
"""The policy of ``uss-demo`` and ``uss-experiments``: no target labels in the protocol."""


def policy_note(policy: str) -> str:
    """How a table says which checkpoints it shows."""
    if policy in USES_TARGET_LABELS:
        return f"checkpoints: {policy} (selected with target labels)"
    return f"checkpoints: {policy} (no target labels used)"


def select_checkpoint(run_dir: Path, policy: str = DEFAULT_POLICY) -> Path:
    """The checkpoint of training run ``run_dir`` that ``policy`` (a name in
    :data:`CHECKPOINT_POLICIES`) chooses."""
    chosen = CHECKPOINT_POLICIES.get(policy)
    if chosen is None:
        raise UssSlamError(
            f"checkpoint policy {policy!r}: unknown; accepted: {', '.join(CHECKPOINT_POLICIES)}"
        )
    return chosen(Path(run_dir))


def checkpoint_miou(ckpt: Path) -> float | None:
    """``val/mIoU`` recorded in a best checkpoint's name (``best_iter..._miou0.1234.ckpt``;
    None for another name, e.g. ``last.ckpt``)."""
    match = re.search(r"_miou(\d+\.\d+)\.ckpt$", ckpt.name)
    return float(match.group(1)) if match else None


# ------------------------------------------------------------------------- configs


def compose_config(config_name: str, overrides: Sequence[str]) -> DictConfig:
    """Compose one of the package's configs: inside a running Hydra app with its config tree,
    else by initialising Hydra on :data:`CONFIG_DIR` for this one call."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    if GlobalHydra.instance().is_initialized():
        return compose(config_name, overrides=list(overrides))
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose(config_name, overrides=list(overrides))


# ------------------------------------------------------------------------- training


RESUME_FROM = Path("checkpoints/last.ckpt")
"""The file an interrupted training goes on from (inside its run folder)."""


def resume_point(run_dir: Path) -> int | None:
    """The iteration an interrupted training in ``run_dir`` goes on from (its ``last.ckpt``), or
    ``None`` when there is none. A ``last.ckpt`` that cannot be read (the run was killed while
    writing it) is logged, and the run's checkpoints are removed: it starts again."""
    import logging

    from uss_slam.models.checkpoint import read_checkpoint

    path = run_dir / RESUME_FROM
    if not path.is_file():
        return None
    try:
        iteration = read_checkpoint(path).iteration
    except UssSlamError as error:
        iteration, why = None, str(error)
    else:
        why = f"{path}: no 'iteration' (not a uss-train checkpoint)"
    if iteration is None:
        logging.getLogger(__name__).warning("%s; the training starts again", why)
        shutil.rmtree(path.parent)
    return iteration


EARLIER_CSV = ".before-resume.csv"
"""Beside a resumed run's ``metrics.csv``: the rows logged before the resume, until merged."""


def _csv_rows(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with open(path, encoding="utf-8", newline="") as f:
        return list(csv.DictReader(f))


def _step(row: Mapping[str, str]) -> float:
    try:
        return float(row.get("step") or "nan")
    except ValueError:
        return float("nan")


def _joined(earlier: list[dict[str, str]], later: list[dict[str, str]]) -> list[dict[str, str]]:
    """``earlier``'s rows before ``later``'s first step (those after it were logged by the
    interrupted run past its last checkpoint and are logged again), then ``later``'s."""
    first = min((_step(r) for r in later), default=float("inf"))
    return [r for r in earlier if _step(r) < first] + later


def _write_csv(path: Path, rows: list[dict[str, str]]) -> None:
    from uss_slam.core.files import atomic_path

    fields = sorted({k for r in rows for k in r})
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)


@contextmanager
def csv_log_kept(cfg: DictConfig) -> Iterator[None]:
    """Around a resumed training: keep the rows the CSV logger wrote before the resume.

    Lightning's ``CSVLogger`` deletes the ``metrics.csv`` it finds in its folder; a training
    resumed into its own run folder would lose the curve of its first part. The earlier rows
    are set aside first (``.before-resume.csv``, so a kill cannot lose them either) and joined
    in front of the new ones when the training ends, also when it ends by an exception."""
    node = (cfg.get("logger") or {}).get("csv")
    if not node or "_target_" not in node:
        yield
        return
    folder = Path(str(node.save_dir)) / str(node.get("name") or "") / str(node.get("version") or "")
    log, aside = folder / "metrics.csv", folder / EARLIER_CSV
    earlier = _joined(_csv_rows(aside), _csv_rows(log))
    if earlier:
        _write_csv(aside, earlier)
    try:
        yield
    finally:
        if earlier:
            _write_csv(log, _joined(earlier, _csv_rows(log)))
            aside.unlink()


def run_training(run_dir: Path, overrides: Sequence[str], resume: bool = False) -> dict[str, Any]:
    """``uss-train`` with ``overrides`` into ``run_dir`` (``checkpoints/``, the loggers' folders,
    and ``.hydra/config.yaml`` / ``overrides.yaml`` as ``uss-train`` writes them: ``uss-export``
    reads the net's config there); returns the run's final metrics (``val/mIoU``, ...).

    ``resume``: go on from ``run_dir``'s ``checkpoints/last.ckpt`` when an interrupted run left
    one (:func:`resume_point`); the caller makes sure it is a run of the same overrides (a
    :class:`~uss_slam.pipelines.stages.Stage` with ``resume_from``). The metrics then include
    ``resumed_from_iteration``."""
    from omegaconf import OmegaConf

    from uss_slam.train.train import train

    every = [*overrides, path_override("paths.output_dir", run_dir)]
    start = resume_point(run_dir) if resume else None
    if start is not None:
        every.append(path_override("ckpt_path", run_dir / RESUME_FROM))
    cfg = compose_config("train", every)
    hydra_dir = run_dir / ".hydra"
    hydra_dir.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(
        OmegaConf.create(OmegaConf.to_container(cfg, resolve=True)), hydra_dir / "config.yaml"
    )
    OmegaConf.save(OmegaConf.create(every), hydra_dir / "overrides.yaml")
    if start is None:
        return train(cfg)
    with csv_log_kept(cfg), warnings.catch_warnings():
        # Lightning's warnings about the folders it finds filled: here they are the run's own
        for what in ("Checkpoint directory", "Experiment logs directory"):
            warnings.filterwarnings("ignore", message=f"{what} .* exists and is not empty")
        metrics = train(cfg)
    return {**metrics, "resumed_from_iteration": float(start)}


# ------------------------------------------------------------------------- SLAM


@dataclass(frozen=True)
class Segmenter:
    """What segments a SLAM run's frames: nothing, the sequence's labels, or an exported ONNX
    model ``path`` (optionally refined by the dense CRF with ``crf_params``; unset parameters keep
    the CRF's defaults)."""

    kind: str  # none | labels | onnx (uss-slam's segmenter group)
    path: Path | None = None
    crf: bool = False
    crf_params: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in ("none", "labels", "onnx"):
            raise UssSlamError(f"segmenter {self.kind!r}: expected none, labels or onnx")
        if (self.path is None) == (self.kind == "onnx"):
            raise UssSlamError(f"segmenter {self.kind}: a path is for (and only for) onnx")
        if (self.crf or self.crf_params) and self.kind != "onnx":
            raise UssSlamError(f"segmenter {self.kind}: the dense CRF refines an onnx model only")

    @classmethod
    def onnx(
        cls, path: Path, crf: bool = False, crf_params: Mapping[str, Any] | None = None
    ) -> Segmenter:
        """An exported model (``crf_params`` only with ``crf``)."""
        params = tuple((crf_params or {}).items()) if crf else ()
        return cls("onnx", Path(path), crf, params)

    @classmethod
    def of(
        cls,
        variant: Variant,
        model: Path | None = None,
        crf_params: Mapping[str, Any] | None = None,
    ) -> Segmenter:
        """The segmenter of ``variant``; ``model``: the ONNX file of a ``model`` variant."""
        if variant.segmenter != "model":
            return cls(variant.segmenter)
        if model is None:
            raise UssSlamError(f"variant {variant.name}: needs an exported model")
        return cls.onnx(model, variant.crf, crf_params)

    def choice(self) -> list[str]:
        """The overrides choosing the segmenter."""
        if self.path is None:
            return [f"segmenter={self.kind}"]
        return ["segmenter=onnx", path_override("segmenter.path", self.path)]

    def refinement(self) -> list[str]:
        """The overrides of the dense CRF (none without it)."""
        if not self.crf:
            return []
        return [
            "segmenter.crf=true",
            *(f"segmenter.crf_params.{k}={v}" for k, v in self.crf_params),
        ]


@dataclass(frozen=True)
class OrbSlam3:
    """The real ORB-SLAM3 instead of the harness: it gets the dynamic mask blanked out of its
    input (the harness's filters do not apply). ``repeats``: runs whose median it reports."""

    vocabulary: Path
    repeats: int
    overrides: tuple[str, ...] = ()


@dataclass(frozen=True)
class SlamJob:
    """One ``uss-slam`` run: a TUM RGB-D ``sequence`` folder, its :class:`Segmenter`, the
    harness's ``filters`` (in uss-slam's order), ``extra`` ``uss-slam`` overrides, optionally
    ORB-SLAM3 as the system, and ``max_frames`` (None = every frame)."""

    sequence: Path
    segmenter: Segmenter = field(default_factory=lambda: Segmenter("none"))
    filters: tuple[str, ...] = ()
    extra: tuple[str, ...] = ()
    orbslam3: OrbSlam3 | None = None
    max_frames: int | None = None

    def overrides(self) -> list[str]:
        """The ``uss-slam`` overrides of this run (without ``out_dir`` / ``progress``)."""
        out = [path_override("sequence.path", self.sequence), *self.segmenter.choice()]
        if self.orbslam3 is None:
            out.append(f"filters=[{','.join(self.filters)}]")
        out += self.segmenter.refinement()
        out += self.extra
        if self.orbslam3 is not None:
            orb = self.orbslam3
            out += [
                "filters=[]",
                "system=orbslam3",
                path_override("system.vocabulary", orb.vocabulary),
                f"system.repeats={orb.repeats}",
                *orb.overrides,
            ]
        if self.max_frames is not None:
            out.append(f"sequence.max_frames={self.max_frames}")
        return out

    def to_json(self) -> dict[str, Any]:
        """A JSON-able dict that :meth:`from_json` reads back."""
        seg = self.segmenter
        orb = self.orbslam3
        return {
            "sequence": str(self.sequence),
            "segmenter": {
                "kind": seg.kind,
                "path": None if seg.path is None else str(seg.path),
                "crf": seg.crf,
                "crf_params": dict(seg.crf_params),
            },
            "filters": list(self.filters),
            "extra": list(self.extra),
            "orbslam3": None
            if orb is None
            else {
                "vocabulary": str(orb.vocabulary),
                "repeats": orb.repeats,
                "overrides": list(orb.overrides),
            },
            "max_frames": self.max_frames,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any], where: str = "SLAM job") -> SlamJob:
        """The job :meth:`to_json` wrote; ``where`` names the source in the error line."""
        try:
            seg = data["segmenter"]
            orb = data.get("orbslam3")
            return cls(
                sequence=Path(data["sequence"]),
                segmenter=Segmenter(
                    seg["kind"],
                    None if seg.get("path") is None else Path(seg["path"]),
                    bool(seg.get("crf", False)),
                    tuple(dict(seg.get("crf_params") or {}).items()),
                ),
                filters=tuple(data.get("filters") or ()),
                extra=tuple(data.get("extra") or ()),
                orbslam3=None
                if orb is None
                else OrbSlam3(
                    Path(orb["vocabulary"]), int(orb["repeats"]), tuple(orb.get("overrides") or ())
                ),
                max_frames=None if data.get("max_frames") is None else int(data["max_frames"]),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as error:
            raise UssSlamError(
                f"{where}: not a SLAM job ({type(error).__name__}: {error})"
            ) from None


def compose_slam(job: SlamJob, out_dir: Path, *, progress: bool = False) -> DictConfig:
    """The ``uss-slam`` config of ``job`` writing into ``out_dir``."""
    from uss_slam.slam_eval.config import register_configs

    # The typed slam / eval defaults, every time: a launcher's worker process (joblib, submitit)
    # gets Hydra's ConfigStore as it was when the jobs were launched, not as this module left it.
    register_configs()
    return compose_config(
        "slam_eval", [*job.overrides(), f"out_dir={out_dir}", f"progress={str(progress).lower()}"]
    )


_PATHS = (("sequence", "path"), ("segmenter", "path"), ("system", "vocabulary"))
"""Entries of the composed config that name files: a cache key holds their content instead."""

_TIMING_ONLY = (("slam", "reuse_labels"),)
"""Entries that change how long a run takes and none of its trajectories (tested): a run made
with either value stays valid."""


@functools.lru_cache(maxsize=1)
def slam_defaults_key() -> str:
    """SHA-256 of ``uss-slam``'s settings without overrides (the composed config, its
    output folder and file paths aside). A cache of SLAM runs keyed on a job's overrides
    alone would keep a run made under other defaults (another tracker policy, say). With this
    in the key, a changed default redoes the run, as a changed override does."""
    from omegaconf import OmegaConf

    cfg = OmegaConf.to_container(compose_slam(SlamJob(Path(".")), Path(".")), resolve=True)
    assert isinstance(cfg, dict)
    for name in ("out_dir", "progress", "variant"):  # (jobs give their variant's keys)
        cfg.pop(name, None)
    for section, name in (*_PATHS, *_TIMING_ONLY):
        if isinstance(cfg.get(section), dict):
            cfg[section].pop(name, None)
    text = json.dumps(cfg, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def run_slam(job: SlamJob, out_dir: Path, *, progress: bool = False) -> dict[str, Any]:
    """Run ``job`` into ``out_dir``; returns ``uss-slam``'s metrics of the run (``ate``,
    ``tracked_fraction``, ``fps`` in frames/s, ...)."""
    from uss_slam.slam_eval.run import run

    return run(compose_slam(job, out_dir, progress=progress))
