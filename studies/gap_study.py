"""The real-regime study's measurements (``docs/results/protocol.md``, "the real regime"): what
every primary figure is computed from, written as small committed files.

A study folder ``STUDY`` is one ``uss-experiments`` output folder (``stages=[data,train,export]``,
``init.style=source``): its trainings all start from ``data/init/i0/init.ckpt`` at one budget.
Sub-commands:

- ``check STUDY``: every training of the folder started from the same init and ran the same
  budget (``model.max_iters``, ``model.optimizer.lr``); else one line naming the file.
- ``export-init STUDY``: the init as is (``exports/init/init.onnx``) and with BatchNorm
  statistics of 48 unlabelled target training frames (``exports/init_adabn/``), the rows that
  need no training.
- ``score STUDY --renders DIR --blocks 8100,8200 --role pilot|eval --out FILE.csv``: each export's
  ``(4, 4)`` confusion matrix (rows: truth; columns: prediction; pixels; classes background,
  person, chair, monitor) on every ``--stride``-th frame of each render
  ``DIR/<preset>_<block + i>`` (walking_xyz, walking_rpy, walking_halfsphere: i = 0, 1, 2; with
  ``--first N`` only its first N frames), one CSV row per model and render. An ``eval`` block
  whose seeds ``docs/results/read_renders.csv`` lists as read by another study is refused
  before any work; scored eval seeds are added to it.
- ``dacc STUDY --out FILE.csv``: every adversarial training's discriminator accuracy per head
  over training (``train/d_acc_<head>`` of its ``csv/metrics.csv``, the share of patches whose
  domain the discriminator gets right; 0.5 = chance), averaged over blocks of 25 iterations.
- ``false-alarm STUDY --frames DIR [DIR ...] --out FILE.csv``: each export's predicted person
  pixels per frame on real frame folders (``rgb.txt``) that show no people.
- ``ate-cost RUNS --out FILE.csv``: the semantic filter's ATE cost there: each ``uss-slam``
  output folder ``RUNS/<model>/`` (``segmenter=onnx filters=[semantic] slam.repeats=3``) against
  the unfiltered ``RUNS/none/``: median ATE RMSE, the repeats' range, the ratio.

The figures: ``python studies/gap_figures.py`` on the committed CSVs.
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from PIL import Image

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.seg_metrics import confusion_matrix

PRESETS = ("walking_xyz", "walking_rpy", "walking_halfsphere")
"""Render ``i`` of a seed block: preset ``PRESETS[i]`` with seed block + ``i``."""
READ_LIST = Path(__file__).resolve().parents[1] / "docs" / "results" / "read_renders.csv"
"""The record of evaluation render seeds read by a run: ``seed,study`` rows."""
MODEL = re.compile(r"^(?P<row>.+?)(?:_s(?P<seed>\d+))?$")
N = len(CLASS_NAMES)
DACC_BLOCK = 25


class StudyError(SystemExit):
    """A bad input: one line naming the key or file, before any work."""

    def __init__(self, message: str) -> None:
        super().__init__(f"gap_study: error: {message}")


def parse_blocks(text: str) -> list[int]:
    """``"8100,8200"`` -> ``[8100, 8200]`` (positive integers, each once)."""
    try:
        blocks = [int(b) for b in text.split(",") if b.strip()]
    except ValueError:
        raise StudyError(f"--blocks: expected comma-separated integers, got {text!r}") from None
    if not blocks or len(set(blocks)) != len(blocks) or min(blocks) < 0:
        raise StudyError(f"--blocks: expected distinct integers >= 0, got {text!r}")
    return blocks


def render_folders(root: Path, blocks: list[int]) -> list[tuple[str, int, int, Path]]:
    """``(preset, block, seed, folder)`` of every render of ``blocks``; a missing one exits."""
    found = []
    for block in blocks:
        for i, preset in enumerate(PRESETS):
            folder = root / f"{preset}_{block + i}"
            if not (folder / "rgb.txt").is_file() or not (folder / "labels").is_dir():
                raise StudyError(f"{folder}: no render (rgb.txt and labels/); render it first")
            found.append((preset, block, block + i, folder))
    return found


def read_list(path: Path = READ_LIST) -> dict[int, str]:
    """``{seed: study}`` of the evaluation render seeds the record lists as read."""
    if not path.is_file():
        return {}
    with open(path, newline="") as f:
        return {int(r["seed"]): r["study"] for r in csv.DictReader(f)}


def check_unread(seeds: list[int], study: str, path: Path = READ_LIST) -> None:
    """An evaluation seed read by another study: one line naming the file and the seed."""
    read = read_list(path)
    used = [s for s in seeds if s in read and read[s] != study]
    if used:
        raise StudyError(
            f"{path}: evaluation render seed(s) {', '.join(map(str, used))} already read by "
            f"{', '.join(sorted({read[s] for s in used}))}; choose a block no run has read"
        )


def mark_read(seeds: list[int], study: str, path: Path = READ_LIST) -> None:
    read = read_list(path)
    new = [s for s in seeds if s not in read]
    if not new:
        return
    fresh = not path.is_file()
    with open(path, "a", newline="") as f:
        writer = csv.writer(f)
        if fresh:
            writer.writerow(["seed", "study"])
        writer.writerows([s, study] for s in new)


def training_configs(study: Path) -> Iterator[tuple[Path, dict]]:
    """Each training's composed config (``train/<id>/.hydra/config.yaml``)."""
    import yaml

    for path in sorted((study / "train").glob("*/.hydra/config.yaml")):
        yield path, yaml.safe_load(path.read_text())


def check_study(study: Path) -> dict[str, object]:
    """One init and one budget for every training; returns them. Else one line naming the file
    that differs and the key."""
    seen: dict[str, tuple[object, Path]] = {}
    count = 0
    for path, cfg in training_configs(study):
        count += 1
        model = cfg["model"]
        values = {
            "model.net.weights_path": model["net"].get("weights_path"),
            "model.max_iters": model["max_iters"],
            "model.optimizer.lr": model["optimizer"]["lr"],
        }
        for key, value in values.items():
            if key not in seen:
                seen[key] = (value, path)
            elif seen[key][0] != value:
                raise StudyError(
                    f"{path}: {key}={value}, but {seen[key][1]} has {seen[key][0]}; a study "
                    "folder's rows must share one init and one budget"
                )
    if not count:
        raise StudyError(f"{study / 'train'}: no training with a .hydra/config.yaml")
    init = seen["model.net.weights_path"][0]
    if init is None:
        raise StudyError(f"{seen['model.net.weights_path'][1]}: model.net.weights_path is null; "
                         "the study's rows start from a pretrained init")  # fmt: skip
    return {k: v for k, (v, _) in seen.items()} | {"trainings": count}


def target_frames(study: Path) -> list[Path]:
    """The study's unlabelled target training folders (AdaBN's statistics)."""
    folders = sorted(p for p in (study / "data" / "train" / "target_train").iterdir() if p.is_dir())
    if not folders:
        raise StudyError(f"{study}/data/train/target_train: no target training folder")
    return folders


def export_init(study: Path) -> list[Path]:
    """``exports/init`` and ``exports/init_adabn`` from ``data/init/i0/init.ckpt``."""
    from uss_slam.datasets.transforms import eval_transform
    from uss_slam.datasets.tum import TUMFrames
    from uss_slam.export.onnx import export_checkpoint
    from uss_slam.pipelines.experiments.plan import ADABN_BATCH_SIZE, ADABN_IMAGES
    from uss_slam.train.precise_bn import adabn

    # init.ckpt is a copy of the run's last.ckpt, whose .hydra/ the export reads the net from
    init = study / "data" / "init" / "i0" / "init.ckpt"
    ckpt = init.parent / "checkpoints" / "last.ckpt"
    if not init.is_file() or not ckpt.is_file():
        raise StudyError(f"{init}: no init; run the study's data stage first")
    if init.read_bytes() != ckpt.read_bytes():
        raise StudyError(f"{ckpt}: differs from {init}; the init's run was changed after it")
    folders = target_frames(study)

    def prepare(net: object) -> None:
        target = TUMFrames(folders, labels=False, transform=eval_transform())
        adabn(net, target, images=ADABN_IMAGES, batch_size=ADABN_BATCH_SIZE)

    out = []
    for name, options in (("init", {}), ("init_adabn", {"prepare": prepare})):
        path = study / "exports" / name / f"{name}.onnx"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            export_checkpoint(ckpt, path, experiment=name, **options)
        out.append(path)
    return out


def exports(study: Path, names: list[str] | None = None) -> list[tuple[str, str, str, Path]]:
    """``(model, row, seed, onnx)`` of every export of the study (``names`` keeps some)."""
    found = []
    for path in sorted((study / "exports").glob("*/*.onnx")):
        model = path.stem
        if path.parent.name != model or (names and model not in names):
            continue
        match = MODEL.match(model)
        assert match is not None
        found.append((model, match["row"], match["seed"] or "", path))
    if not found:
        raise StudyError(f"{study / 'exports'}: no exported model")
    return found


def frame_files(folder: Path, stride: int, first: int | None = None) -> list[str]:
    """Every ``stride``-th frame of the first ``first`` frames of ``rgb.txt`` (all when None;
    file names relative to the folder)."""
    lines = [ln.split() for ln in (folder / "rgb.txt").read_text().splitlines()]
    files = [parts[1] for parts in lines if parts and not parts[0].startswith("#")]
    return files[:first][::stride]


def score(study: Path, renders: list[tuple[str, int, int, Path]], stride: int,
          names: list[str] | None, role: str, first: int | None = None) -> list[dict]:  # fmt: skip
    """One row per (model, render): the ``(N, N)`` confusion matrix flattened (``c<t><p>``)."""
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

    models = exports(study, names)
    nets = {m: OnnxSegmenter(path, threads=1) for m, _, _, path in models}
    rows = []
    for preset, block, seed, folder in renders:
        files = frame_files(folder, stride, first)
        if first is not None and len(files) < len(range(0, first, stride)):
            raise StudyError(f"{folder}/rgb.txt: fewer than --first {first} frames")
        totals = {m: np.zeros((N, N), np.int64) for m in nets}
        for name in files:
            rgb = np.asarray(Image.open(folder / name).convert("RGB"))
            truth = np.asarray(Image.open(folder / "labels" / Path(name).name))
            for m, net in nets.items():
                totals[m] += confusion_matrix(truth, net.infer(rgb), N)
        for model, row, mseed, _ in models:
            flat = {f"c{t}{p}": int(totals[model][t, p]) for t in range(N) for p in range(N)}
            rows.append({"role": role, "model": model, "row": row, "seed": mseed,
                         "preset": preset, "block": block, "render_seed": seed,
                         "frames": len(files), **flat})  # fmt: skip
        print(f"scored {folder.name}: {len(files)} frames x {len(nets)} models", flush=True)
    return rows


def dacc(study: Path) -> list[dict]:
    """Discriminator accuracy per head over training, in blocks of ``DACC_BLOCK`` iterations."""
    rows = []
    for path in sorted((study / "train").glob("*/csv/metrics.csv")):
        with open(path, newline="") as f:
            logged = list(csv.DictReader(f))
        for head in ("main", "aux"):
            key = f"train/d_acc_{head}"
            values = [(int(r["step"]), float(r[key])) for r in logged if r.get(key)]
            blocks: dict[int, list[float]] = {}
            for step, value in values:
                blocks.setdefault(step // DACC_BLOCK, []).append(value)
            model = path.parents[1].name
            match = MODEL.match(model)
            assert match is not None
            rows += [{"model": model, "row": match["row"], "seed": match["seed"] or "",
                      "head": head, "step": (b + 1) * DACC_BLOCK, "d_acc": round(float(np.mean(v)), 4)}
                     for b, v in sorted(blocks.items())]  # fmt: skip
    return rows


def false_alarm(
    study: Path, folders: list[Path], names: list[str] | None, stride: int
) -> list[dict]:
    """Predicted person pixels (share of the frame) per model and frame on real frames."""
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

    person = CLASS_NAMES.index("person")
    rows = []
    for model, row, seed, path in exports(study, names):
        net = OnnxSegmenter(path, threads=1)
        for folder in folders:
            if not (folder / "rgb.txt").is_file():
                raise StudyError(f"{folder}: no rgb.txt (a TUM-format frame folder)")
            for name in frame_files(folder, stride):
                pred = net.infer(np.asarray(Image.open(folder / name).convert("RGB")))
                rows.append({"model": model, "row": row, "seed": seed, "sequence": folder.name,
                             "frame": Path(name).stem,
                             "person_share": round(float((pred == person).mean()), 6)})  # fmt: skip
    return rows


def ate_cost(runs: Path) -> list[dict]:
    """The semantic filter's ATE cost on frames without people: per ``uss-slam`` output folder
    ``runs/<model>/`` its median ATE RMSE over repeats (m) with the repeats' range, and its ratio
    to the unfiltered run ``runs/none/``."""

    def ate(folder: Path) -> tuple[float, float, float]:
        path = folder / "metrics.json"
        if not path.is_file():
            raise StudyError(f"{path}: no such file (a finished uss-slam run)")
        m = json.loads(path.read_text())
        r = m.get("ate_rmse_repeats") or {}
        return m["ate"]["rmse"], r.get("min", m["ate"]["rmse"]), r.get("max", m["ate"]["rmse"])

    base = ate(runs / "none")[0]
    rows = []
    for folder in sorted(p for p in runs.iterdir() if (p / "metrics.json").is_file()):
        med, lo, hi = ate(folder)
        rows.append({"model": folder.name, "ate_median_m": round(med, 6), "ate_min_m": round(lo, 6),
                     "ate_max_m": round(hi, 6), "ratio_to_none": round(med / base, 4)})  # fmt: skip
    return rows


def write_csv(rows: list[dict], path: Path) -> None:
    if not rows:
        raise StudyError(f"{path}: nothing to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {len(rows)} rows to {path}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ate_p = sub.add_parser("ate-cost")
    ate_p.add_argument("runs", type=Path)
    ate_p.add_argument("--out", type=Path, required=True)
    for name in ("check", "export-init", "score", "dacc", "false-alarm"):
        p = sub.add_parser(name)
        p.add_argument("study", type=Path)
        if name in ("score", "dacc", "false-alarm"):
            p.add_argument("--out", type=Path, required=True)
        if name in ("score", "false-alarm"):
            p.add_argument("--models", help="comma-separated export names (default: all)")
            p.add_argument("--stride", type=int, default=5, help="every N-th frame (default 5)")
    score_p = sub.choices["score"]
    score_p.add_argument("--renders", type=Path, required=True)
    score_p.add_argument("--blocks", required=True)
    score_p.add_argument("--role", choices=("pilot", "eval"), required=True)
    score_p.add_argument("--first", type=int, help="score only the first N frames of a render")
    score_p.add_argument("--name", default="real_regime", help="the study's name in the read list")
    sub.choices["false-alarm"].add_argument("--frames", type=Path, nargs="+", required=True)
    args = parser.parse_args(argv)
    if args.command == "ate-cost":
        if not (args.runs / "none").is_dir():
            raise StudyError(f"{args.runs}/none: no unfiltered run to compare with")
        return write_csv(ate_cost(args.runs), args.out)
    study = args.study
    if not study.is_dir():
        raise StudyError(f"{study}: no study folder")
    names = args.models.split(",") if getattr(args, "models", None) else None
    if getattr(args, "stride", 1) < 1:
        raise StudyError(f"--stride: expected an integer >= 1, got {args.stride}")
    if args.command == "check":
        print(json.dumps(check_study(study), indent=1))
    elif args.command == "export-init":
        check_study(study)
        print("\n".join(map(str, export_init(study))))
    elif args.command == "score":
        blocks = parse_blocks(args.blocks)
        seeds = [b + i for b in blocks for i in range(len(PRESETS))]
        if args.role == "eval":
            check_unread(seeds, args.name)
        check_study(study)
        rows = score(study, render_folders(args.renders, blocks), args.stride, names, args.role,
                     args.first)  # fmt: skip
        write_csv(rows, args.out)
        if args.role == "eval":
            mark_read(seeds, args.name)
    elif args.command == "dacc":
        write_csv(dacc(study), args.out)
    else:
        write_csv(false_alarm(study, args.frames, names, args.stride), args.out)


if __name__ == "__main__":
    sys.exit(main())
