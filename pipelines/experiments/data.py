"""The ``data`` stage of ``uss-experiments``: the synthetic data rendered into ``out_dir/data``
(the demo data set for training; each evaluation sequence with a held-out seed), or the real
folders checked; and ORB-SLAM3's vocabulary when a system needs it."""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uss_slam.core.errors import DataFormatError
from uss_slam.core.files import content_key
from uss_slam.core.processes import pool_ending_with_parent
from uss_slam.pipelines.stages import Stage

from .experiment import TUM_PREFIX, Experiment, eval_seed


@dataclass
class Data:
    """Where the data of the run is, and the keys that say what it is."""

    train_key: Any = None  # what the trainings read (synthetic: uss-synth's demo.yaml)
    train_dir: Path | None = None  # synthetic training data (paths.data_dir)
    sequences: dict[str, Path] = field(default_factory=dict)  # evaluation sequence -> folder
    sequence_keys: dict[str, Any] = field(default_factory=dict)
    labelled: list[str] = field(default_factory=list)  # sequences with labels/
    target: list[Path] = field(default_factory=list)  # the training target sequences
    source_val: Path | None = None  # the source's VOC tree (its val split: T0's in-domain column)
    source_val_key: Any = None
    vocabulary: Path | None = None  # ORB-SLAM3's vocabulary (systems with orbslam3)
    vocabulary_key: Any = None
    init: dict[int | None, Path] = field(default_factory=dict)
    """The pretrained init every training starts from (``init.kind=pretrained``), by init seed
    (``None``: ``init.path``); empty: from scratch."""
    init_keys: dict[int | None, str | None] = field(default_factory=dict)
    """The sha256 of each init file (None while an init is still to be trained: dry run)."""


def synthetic_data_spec(exp: Experiment) -> Any:
    """The training part of the synthetic data (the demo data set without SLAM sequences)."""
    from uss_slam.pipelines.synthetic_data import DemoData
    from uss_slam.synthetic.output import parse_size

    syn = exp.cfg["data"]["synthetic"]
    return DemoData(
        seed=int(syn["seed"]),
        voc_images=int(syn["voc_images"]),
        voc_size=parse_size(str(syn["voc_size"])),
        train_frames=int(syn["train_frames"]),
        val_frames=int(syn["val_frames"]),
        train_size=parse_size(str(syn["train_size"])),
        slam_frames=0,
        source_outfits=None if syn.get("source_outfits") is None else str(syn["source_outfits"]),
        shift=str(syn.get("shift", "tum_like")),
    )


def sequence_stage(exp: Experiment, name: str) -> Stage:
    from uss_slam.pipelines.synthetic_data import SHIFT_OUTFITS

    syn = exp.cfg["data"]["synthetic"]
    shift = str(syn.get("shift", "tum_like"))
    key: dict[str, Any] = {
        "preset": name,
        "frames": int(syn["eval_frames"]),
        "size": str(syn["eval_size"]),
        "seed": eval_seed(exp.cfg, name),
        "style": "target",
    }
    folder = exp.out / "data" / "eval" / name
    if shift == "appearance":
        # the source's content in the target style: labelled images, no recording to track
        key |= {"images": True, "outfits": synthetic_data_spec(exp).wardrobe}
        return Stage(folder, key, outputs=(Path("rgb.txt"), Path("labels")))
    if SHIFT_OUTFITS[shift] != "office":  # keys of sequences rendered before shifts existed
        key["outfits"] = SHIFT_OUTFITS[shift]
    return Stage(folder, key, outputs=(Path("rgb.txt"), Path("groundtruth.txt"), Path("labels")))


def render_eval_sequence(folder: Path, key: dict[str, Any]) -> Path:
    """Render an evaluation sequence (or, for the appearance shift, image folder) from its stage
    key (in a worker process)."""
    from uss_slam.synthetic.output import parse_size
    from uss_slam.synthetic.sequence import render_sequence
    from uss_slam.synthetic.voc import render_voc_frames

    if key.get("images"):
        return render_voc_frames(folder, images=key["frames"], size=parse_size(key["size"]),
                                 seed=key["seed"], outfits=key["outfits"], style=key["style"],
                                 overwrite=True)  # fmt: skip
    return render_sequence(
        folder,
        preset=key["preset"],
        frames=key["frames"],
        size=parse_size(key["size"]),
        seed=key["seed"],
        style=key["style"],
        outfits=key.get("outfits", "office"),
        overwrite=True,
    )


def stage_data(exp: Experiment, run: bool, dry: bool = False) -> tuple[Data, str]:
    """Render (``run``) or find the data; returns it and a status line. ``dry``: what is
    missing is reported, not an error."""
    data, status = _synthetic_data(exp, run, dry) if exp.synthetic else _real_data(exp)
    if "orbslam3" in exp.grid.systems:
        status += ", " + _vocabulary(exp, data, run, dry)
    return data, status


def _vocabulary(exp: Experiment, data: Data, run: bool, dry: bool) -> str:
    """ORB-SLAM3's vocabulary: the configured file, or one built from the training target
    frames (uss-vocab build's defaults) into ``out_dir/data/orbslam3_vocabulary``."""
    from uss_slam.slam_eval.systems.orbslam3.vocabulary import build_from_sequences

    given = exp.cfg["slam"]["orbslam3"].get("vocabulary")
    if given is not None:
        data.vocabulary = Path(os.path.expanduser(str(given))).resolve()
        data.vocabulary_key = str(data.vocabulary)
        return f"ORB-SLAM3 vocabulary {data.vocabulary}"
    key = {"target": data.train_key, "folders": [str(p) for p in data.target]}
    stage = Stage(exp.out / "data" / "orbslam3_vocabulary", key, outputs=(Path("vocabulary.txt"),))
    data.vocabulary = stage.folder / "vocabulary.txt"
    data.vocabulary_key = key
    if stage.complete():
        return "ORB-SLAM3 vocabulary reused"
    if dry:
        return "ORB-SLAM3 vocabulary to build"
    if not run:
        raise DataFormatError(
            stage.folder, "missing or incomplete ORB-SLAM3 vocabulary; run the data stage"
        )
    stage.start()
    report = build_from_sequences(data.target, data.vocabulary)
    stage.finish()
    return f"ORB-SLAM3 vocabulary built from {report.images} target frames ({report.words} words)"


def _synthetic_data(exp: Experiment, run: bool, dry: bool) -> tuple[Data, str]:
    from uss_slam.pipelines import synthetic_data

    data = Data(train_dir=exp.out / "data" / "train")
    assert data.train_dir is not None
    spec = synthetic_data_spec(exp)
    done = []
    if run:
        if synthetic_data.is_complete(data.train_dir, spec):
            done.append("training data reused")
        else:
            # replaces an earlier (other-sized) data set only once the new one is complete
            synthetic_data.render_demo_data(data.train_dir, spec, overwrite=True, progress=False)
            done.append("training data rendered")
        print(synthetic_data.summarize(data.train_dir), flush=True)
    record = data.train_dir / synthetic_data.RECORD
    if not synthetic_data.is_complete(data.train_dir, spec) and dry:
        done.append(f"training data to render into {data.train_dir}")
    elif not synthetic_data.is_complete(data.train_dir, spec):
        raise DataFormatError(
            data.train_dir,
            "missing or incomplete synthetic training data (its demo.yaml is "
            "missing or records other settings); run the data stage (stages=[data,...])",
        )
    data.train_key = record.read_text(encoding="utf-8") if record.is_file() else None
    data.target = [data.train_dir / f for f in spec.target_folders()]
    data.source_val = data.train_dir / "voc"
    data.source_val_key = data.train_key  # the VOC tree is part of the training data
    missing = []
    for name in exp.grid.sequences:
        stage = sequence_stage(exp, name)
        if not stage.complete() and dry:
            done.append(f"{name} to render")
        elif not stage.complete():
            if not run:
                raise DataFormatError(
                    stage.folder, "missing or incomplete evaluation sequence; run the data stage"
                )
            missing.append(stage)
        data.sequences[name] = stage.folder
        data.sequence_keys[name] = dict(stage.key)
        data.labelled.append(name)
    # The sequences are independent: rendered on two processes (PNG writing costs as much as
    # the rendering at 640x480), each stamped as soon as it is complete.
    if missing:
        workers = min(2, os.cpu_count() or 1)
        with ProcessPoolExecutor(max_workers=workers, **pool_ending_with_parent()) as pool:
            for stage in missing:
                stage.start()
            futures = {pool.submit(render_eval_sequence, s.folder, dict(s.key)): s for s in missing}
            for future in as_completed(futures):
                future.result()
                futures[future].finish()
    rendered = len(missing)
    if run:
        done.append(
            f"{len(exp.grid.sequences)} evaluation sequences "
            f"({rendered} rendered, {len(exp.grid.sequences) - rendered} reused)"
        )
    return data, ", ".join(done) or "training data and evaluation sequences complete (reused)"


def _real_data(exp: Experiment) -> tuple[Data, str]:
    from uss_slam.core.tum_io import read_tum_folder
    from uss_slam.datasets.sbd import find_sbd_root
    from uss_slam.datasets.voc import find_voc_root

    real = exp.cfg["data"]["real"]
    voc = find_voc_root(real["voc"])
    val_list = voc / "ImageSets" / "Segmentation" / "val.txt"
    if any(s.source_val for s in exp.grid.segevals) and not val_list.is_file():
        raise DataFormatError(
            val_list, "missing: T0's in-domain column scores the VOC val split "
            "(segeval.source_val_stride=null leaves it out)"
        )  # fmt: skip
    find_sbd_root(real["sbd"])
    coco = Path(os.path.expanduser(str(real["coco"])))
    for needed in (coco / "annotations" / "instances_train2017.json", coco / "train2017"):
        if not needed.exists():
            raise DataFormatError(
                needed,
                "incomplete COCO folder: expected annotations/"
                "instances_train2017.json and train2017/",
            )
    tum = Path(os.path.expanduser(str(real["tum"])))
    targets = [tum / f"{TUM_PREFIX}{t}" for t in real["target"]]
    for folder in targets:
        read_tum_folder(folder, depth=False)
    # keys of content, not of names: a changed file under a folder redoes what reads it
    sources = {k: Path(os.path.expanduser(str(real[k]))) for k in ("voc", "sbd", "coco")}
    keys = {k: content_key(p) for k, p in sources.items()}
    data = Data(
        train_key=keys | {"target": [content_key(t) for t in targets]},
        target=targets,
        source_val=sources["voc"],
        source_val_key=keys["voc"],  # the same tree as the training source: one walk
    )
    for name in exp.grid.sequences:
        folder = tum / f"{TUM_PREFIX}{name}"
        lists = read_tum_folder(folder, depth=True)
        if lists.groundtruth is None:
            raise DataFormatError(folder / "groundtruth.txt", "missing: the SLAM runs need it")
        data.sequences[name] = folder
        data.sequence_keys[name] = content_key(folder)
        if (folder / "labels").is_dir():
            data.labelled.append(name)
    if "oracle" in exp.grid.variants:
        unlabelled = [n for n in exp.grid.sequences if n not in data.labelled]
        if unlabelled:
            folder = data.sequences[unlabelled[0]]
            raise DataFormatError(
                folder / "labels",
                "missing: variant oracle (ground-truth "
                "masks) needs labels/ in every evaluation sequence",
            )
    status = (
        f"real data checked: VOC, SBD, COCO, {len(targets)} target and "
        f"{len(data.sequences)} evaluation sequences ({len(data.labelled)} labelled)"
    )
    return data, status
