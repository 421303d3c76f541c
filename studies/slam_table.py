"""Does a SLAM default hold on every real stretch at every frame rate, with repeats, against
ORB-SLAM3? One command runs every TUM stretch in ``--data`` (and synthetic hand-held sequences
with a global and a rolling shutter) at every ``--strides`` frame step (default 1-5), through the harness with
its defaults (local bundle adjustment + loop closing), the harness without back end
(``slam.local_ba=false slam.loop_closing=false``) and ORB-SLAM3, each ``--repeats`` times, and
prints one table: per sequence × stride × system the median ATE RMSE, its (min–max) and max/min
spread, and the ratios harness default / ORB-SLAM3 and default / no back end. Results: the
"SLAM on real frames" section of docs/results/slam.md (every run: docs/results/slam_table/README.md).

    python studies/slam_table.py --out outputs/bench/slam_table
    python studies/slam_table.py --data ../shared/data/tum --repeats 5 --strides 1,2,3,4,5 \\
        --systems harness,harness_noback,orbslam3 --synthetic --out outputs/bench/slam_table
    python studies/slam_table.py --no-real --synthetic-presets handheld_fast --strides 1,2

Every run goes through the console scripts (``uss-slam``, ``uss-vocab``, ``uss-synth``), one
folder per cell under ``<out>/runs/<sequence>/stride<k>/<system>/``; a rerun reuses a cell whose
folder holds a complete run (``run.json``) with as many repeats as asked, unless ``--force``.
The harness repeats are ``slam.repeats`` (seeded ±1% feature budget and RANSAC order), ORB-SLAM3's
``system.repeats`` (its threads); the figures are the folder's ``metrics.json``
``ate_rmse_repeats`` (median run, for an even count the lower middle one; min; max).
ORB-SLAM3's vocabulary (``uss-vocab build``) never sees the frames it is scored on: a real stretch
gets one built from the other stretches in ``--data``, a synthetic sequence one built from the
same preset rendered with another seed. The real stretches use ``--camera`` (TUM fr1 for
freiburg1); the synthetic ones their own ``intrinsics.yaml``. The synthetic presets
(``--synthetic-presets``) are ``handheld_rpy`` (TUM fr1/rpy-like: up to ~80°/s, ~40 on average)
and ``handheld_fast`` (the same path 4× faster: up to ~300°/s, ~155 on average); a stride ``k``
multiplies the motion between the frames used by ``k``. Writes ``<out>/table.md`` and
``<out>/table.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from uss_slam.testing.machine import cpu_model

SYSTEMS = {
    "harness": ("harness (default)", []),
    "harness_noback": ("harness, no back end", ["slam.local_ba=false", "slam.loop_closing=false"]),
    "orbslam3": ("ORB-SLAM3", []),
}
"""System key -> (column title, uss-slam overrides besides the sequence and repeats)."""

SYNTHETIC_PRESETS = ("handheld_rpy", "handheld_fast")
SYNTHETIC_TIMINGS = ("global", "rolling")
SYNTHETIC_SEED = 0
VOCAB_SEED = 1
"""Seed of the synthetic sequence the synthetic cells' vocabulary is built from."""

DEFAULT_DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "tum"


class TableError(Exception):
    """A bad input or a failed step: one line for the user."""


@dataclass
class Sequence:
    name: str
    path: Path
    kind: str  # "real" | "synthetic"
    camera: str | None
    vocab_sources: list[Path] = field(default_factory=list)


def tool(name: str) -> str:
    """The console script ``name`` of this interpreter's environment, else on PATH."""
    here = Path(sys.executable).parent / name
    if here.is_file():
        return str(here)
    found = shutil.which(name)
    if found is None:
        raise TableError(f"{name}: console script not found (install uss-slam: pip install -e .)")
    return found


def run_tool(cmd: list[str], what: str) -> None:
    """Run ``cmd``; on failure raise with the last line it wrote to stderr."""
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        lines = [ln for ln in (proc.stderr or proc.stdout).splitlines() if ln.strip()]
        last = lines[-1] if lines else f"exit code {proc.returncode}"
        raise TableError(f"{what} failed: {last}")


def parse_strides(text: str) -> list[int]:
    try:
        strides = [int(s) for s in text.split(",")]
    except ValueError:
        strides = []
    if not strides or any(s < 1 for s in strides):
        raise TableError(f"--strides: expected comma-separated integers >= 1, got {text!r}")
    return strides


def parse_systems(text: str) -> list[str]:
    systems = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in systems if s not in SYSTEMS]
    if not systems or unknown:
        raise TableError(
            f"--systems: expected a comma-separated subset of {','.join(SYSTEMS)}, got {text!r}"
        )
    return systems


def parse_size(text: str) -> str:
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.isdigit() and int(p) > 0 for p in parts):
        raise TableError(f"--synthetic-size: expected WxH, e.g. 640x480, got {text!r}")
    return text.lower()


def real_sequences(data: Path, camera: str) -> list[Sequence]:
    """Every TUM sequence folder (``rgb.txt`` + ``groundtruth.txt``) directly in ``data``; each
    one's vocabulary comes from all the others."""
    if not data.is_dir():
        raise TableError(f"--data {data}: no such folder (expected a folder of TUM sequences)")
    paths = sorted(p for p in data.iterdir() if (p / "rgb.txt").is_file())
    if not paths:
        raise TableError(f"--data {data}: no TUM sequence folder (with rgb.txt) in it")
    for p in paths:
        if not (p / "groundtruth.txt").is_file():
            raise TableError(f"{p}: no groundtruth.txt (ATE needs it)")
    return [
        Sequence(p.name, p.resolve(), "real", camera, [q.resolve() for q in paths if q != p])
        for p in paths
    ]


def render(path: Path, preset: str, timing: str, seed: int, frames: int, size: str) -> Path:
    """``uss-synth sequence`` into ``path`` unless a complete one with these arguments is
    there."""
    if (path / "rgb.txt").is_file() and (path / "groundtruth.txt").is_file():
        return path
    cmd = [tool("uss-synth"), "sequence", "--preset", preset, "--timing", timing]
    cmd += ["--frames", str(frames), "--size", size, "--seed", str(seed)]
    cmd += ["--out", str(path), "--overwrite", "--quiet"]
    run_tool(cmd, f"uss-synth into {path}")
    return path


def synthetic_sequences(
    out: Path, frames: int, size: str, presets: list[str], timings: list[str], vocab: bool
) -> list[Sequence]:
    """Each preset × timing rendered with :data:`SYNTHETIC_SEED` (and, for ORB-SLAM3's
    vocabulary, ``vocab``, with :data:`VOCAB_SEED`)."""
    data = out / "data"
    seqs = []
    for preset in presets:
        for timing in timings:
            tag = f"{preset}_{timing}_{frames}f_{size}"
            seed = SYNTHETIC_SEED
            path = render(data / f"{tag}_seed{seed}", preset, timing, seed, frames, size)
            sources = []
            if vocab:
                seed = VOCAB_SEED
                sources.append(
                    render(data / f"{tag}_seed{seed}", preset, timing, seed, frames, size).resolve()
                )
            name = f"synthetic {preset} {timing} shutter"
            seqs.append(Sequence(name, path.resolve(), "synthetic", None, sources))
    return seqs


def slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)


def vocabulary(out: Path, seq: Sequence, force: bool) -> Path:
    """ORB-SLAM3's vocabulary for ``seq``, built once from its ``vocab_sources``."""
    if not seq.vocab_sources:
        raise TableError(
            f"orbslam3 on {seq.name}: no other sequence to build its vocabulary from "
            "(--data needs at least two stretches, or leave orbslam3 out of --systems)"
        )
    path = out / "vocab" / f"{slug(seq.name)}.txt"
    if path.is_file() and not force:
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    cmd = [tool("uss-vocab"), "build", "--out", str(path), "--overwrite"]
    run_tool(cmd + [str(p) for p in seq.vocab_sources], f"uss-vocab build for {seq.name}")
    if not path.is_file():
        raise TableError(f"uss-vocab build for {seq.name}: {path} was not written")
    return path


def cell_command(seq: Sequence, stride: int, system: str, repeats: int, run_dir: Path,
                 vocab: Path | None, overrides: list[str] = ()) -> list[str]:  # fmt: skip
    cmd = [tool("uss-slam"), f"sequence.path={seq.path}", f"sequence.stride={stride}"]
    if seq.camera is not None:
        cmd.append(f"sequence.camera={seq.camera}")
    if system == "orbslam3":
        cmd += ["system=orbslam3", f"system.vocabulary={vocab}", f"system.repeats={repeats}"]
    else:
        cmd += [f"slam.repeats={repeats}", *SYSTEMS[system][1], *overrides]
    return cmd + ["progress=false", f"out_dir={run_dir}"]


def finished(run_dir: Path, repeats: int) -> bool:
    """A complete run (``run.json`` written last) with ``repeats`` repeats."""
    if not (run_dir / "run.json").is_file() or not (run_dir / "metrics.json").is_file():
        return False
    metrics = json.loads((run_dir / "metrics.json").read_text())
    return len(repeat_runs(metrics)) == repeats


def repeat_runs(metrics: dict) -> list[dict]:
    """The per-repeat entries of ``metrics.json``; a harness run without ``slam.repeats`` has
    none, its one run is the folder's own figures."""
    if "repeats" in metrics:
        return metrics["repeats"]
    ate = metrics.get("ate") or {}
    return [{"ate_rmse": ate.get("rmse"), "tracked_fraction": metrics["tracked_fraction"]}]


def cell_figures(run_dir: Path) -> dict:
    """The cell's figures from its run folder's ``metrics.json``."""
    metrics = json.loads((run_dir / "metrics.json").read_text())
    runs = repeat_runs(metrics)
    values = [r["ate_rmse"] for r in runs if r["ate_rmse"] is not None]
    summary = metrics.get("ate_rmse_repeats") or {
        "median": values[0] if values else None,
        "min": values[0] if values else None,
        "max": values[0] if values else None,
        "evaluated": len(values),
    }
    frames = metrics["frames"]
    tracked = [
        r["tracked_fraction"] if "tracked_fraction" in r else r["poses"] / frames for r in runs
    ]
    lo, hi = summary["min"], summary["max"]
    return {
        "ate_rmse_median": summary["median"],
        "ate_rmse_min": lo,
        "ate_rmse_max": hi,
        "spread": hi / lo if lo is not None and hi is not None and lo > 0 else None,
        "evaluated": summary["evaluated"],
        "repeats": len(runs),
        "ate_rmse_per_repeat": [r["ate_rmse"] for r in runs],
        "tracked_fraction_min": min(tracked),
        "frames": frames,
        "run_dir": str(run_dir),
    }


def ratio(a: dict | None, b: dict | None) -> float | None:
    if a is None or b is None or a.get("ate_rmse_median") is None:
        return None
    den = b.get("ate_rmse_median")
    return a["ate_rmse_median"] / den if den else None


def build_rows(seqs: list[Sequence], strides: list[int], cells: dict) -> list[dict]:
    rows = []
    for seq in seqs:
        for stride in strides:
            systems = cells.get((seq.name, stride), {})
            rows.append(
                {
                    "sequence": seq.name,
                    "kind": seq.kind,
                    "stride": stride,
                    "systems": systems,
                    "default_over_orbslam3": ratio(systems.get("harness"), systems.get("orbslam3")),
                    "default_over_noback": ratio(
                        systems.get("harness"), systems.get("harness_noback")
                    ),
                }
            )
    return rows


def fmt_cell(c: dict | None) -> str:
    if c is None:
        return "—"
    if "error" in c:
        return "failed"
    if c["ate_rmse_median"] is None:
        return f"no ATE (0/{c['repeats']} runs, tracked ≥ {c['tracked_fraction_min']:.0%})"
    text = f"{c['ate_rmse_median']:.4f} ({c['ate_rmse_min']:.4f}–{c['ate_rmse_max']:.4f})"
    text += f" ×{c['spread']:.2f}" if c["spread"] is not None else ""
    if c["evaluated"] < c["repeats"]:
        text += f", {c['evaluated']}/{c['repeats']} runs"
    if c["tracked_fraction_min"] < 0.995:
        text += f", tracked ≥ {c['tracked_fraction_min']:.0%}"
    return text


def fmt_ratio(r: float | None) -> str:
    return "—" if r is None else f"{r:.2f}"


def markdown(rows: list[dict], systems: list[str], meta: dict) -> str:
    head = ["sequence", "stride", *(SYSTEMS[s][0] for s in systems)]
    show_orb = "harness" in systems and "orbslam3" in systems
    show_noback = "harness" in systems and "harness_noback" in systems
    head += ["default / ORB-SLAM3"] * show_orb + ["default / no back end"] * show_noback
    lines = [
        f"ATE RMSE in metres: median of {meta['repeats']} repeats (min–max) ×max/min; "
        "ratios of the medians (< 1: the harness default is better).",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for row in rows:
        cols = [row["sequence"], str(row["stride"])]
        cols += [fmt_cell(row["systems"].get(s)) for s in systems]
        cols += [fmt_ratio(row["default_over_orbslam3"])] * show_orb
        cols += [fmt_ratio(row["default_over_noback"])] * show_noback
        lines.append("| " + " | ".join(cols) + " |")
    lines.append("")
    for key, label in (
        ("default_over_noback", "default better than no back end (ratio < 1)"),
        ("default_over_orbslam3", "default better than ORB-SLAM3 (ratio < 1)"),
    ):
        for kind in ("real", "synthetic"):
            values = [r[key] for r in rows if r["kind"] == kind and r[key] is not None]
            if values:
                wins = sum(v < 1 for v in values)
                lines.append(
                    f"- {label}, {kind}: {wins}/{len(values)} rows; median ratio "
                    f"{statistics.median(values):.2f}, worst {max(values):.2f}"
                )
    lines += [f"- {c['error']}" for r in rows for c in r["systems"].values() if "error" in c]
    return "\n".join(lines) + "\n"


def git_commit() -> str | None:
    try:
        proc = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            cwd=Path(__file__).resolve().parent,
        )
    except OSError:
        return None
    return proc.stdout.strip() or None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA,
                        help="folder of TUM sequence folders (default: ../shared/data/tum)")  # fmt: skip
    parser.add_argument("--camera", default="fr1", help="sequence.camera of the real stretches")
    parser.add_argument("--real", action=argparse.BooleanOptionalAction, default=True,
                        help="run the stretches in --data (default: yes)")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--strides", default="1,2,3,4,5")
    parser.add_argument("--systems", default=",".join(SYSTEMS))
    parser.add_argument("--synthetic", action=argparse.BooleanOptionalAction, default=True,
                        help="also synthetic hand-held sequences with a global and a rolling "
                        "shutter (default: yes)")  # fmt: skip
    parser.add_argument("--synthetic-presets", default=",".join(SYNTHETIC_PRESETS),
                        help="uss-synth presets of the synthetic sequences")  # fmt: skip
    parser.add_argument("--synthetic-frames", type=int, default=200)
    parser.add_argument("--synthetic-size", default="640x480", help="WxH")
    parser.add_argument("--synthetic-timings", default=",".join(SYNTHETIC_TIMINGS),
                        help="uss-synth --timing of the synthetic sequences")  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("outputs/bench/slam_table"))
    parser.add_argument("--force", action="store_true", help="rerun finished cells")
    parser.add_argument("--override", action="append", default=[], metavar="KEY=VALUE",
                        help="a uss-slam override for the harness cells (repeatable), e.g. "
                        "slam.tracker.start_as_relocalisation=false")  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print the table as JSON")
    args = parser.parse_args(argv)
    try:
        return run(
            args,
            " ".join(
                ["python", "studies/slam_table.py", *(sys.argv[1:] if argv is None else argv)]
            ),
        )
    except TableError as err:
        print(f"slam_table: error: {err}", file=sys.stderr)
        return 1


def run(args: argparse.Namespace, command: str) -> int:
    bad = [o for o in args.override if "=" not in o or not o.startswith("slam.")]
    if bad:
        raise TableError(f"--override: expected slam.KEY=VALUE, got {bad[0]!r}")
    if args.repeats < 1:
        raise TableError(f"--repeats: expected an integer >= 1, got {args.repeats}")
    if args.synthetic_frames < 2:
        raise TableError(f"--synthetic-frames: expected >= 2, got {args.synthetic_frames}")
    strides = parse_strides(args.strides)
    systems = parse_systems(args.systems)
    size = parse_size(args.synthetic_size)
    timings = [t for t in args.synthetic_timings.split(",") if t]
    if not timings or any(t not in SYNTHETIC_TIMINGS for t in timings):
        raise TableError(
            f"--synthetic-timings: expected a comma-separated subset of "
            f"{','.join(SYNTHETIC_TIMINGS)}, got {args.synthetic_timings!r}"
        )
    presets = [p for p in args.synthetic_presets.split(",") if p]
    if not presets or any(p not in SYNTHETIC_PRESETS for p in presets):
        raise TableError(
            f"--synthetic-presets: expected a comma-separated subset of "
            f"{','.join(SYNTHETIC_PRESETS)}, got {args.synthetic_presets!r}"
        )
    if not args.real and not args.synthetic:
        raise TableError("--no-real and --no-synthetic: nothing to run")
    seqs = real_sequences(args.data, args.camera) if args.real else []
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    load_start = os.getloadavg()
    if args.synthetic:
        seqs += synthetic_sequences(
            out, args.synthetic_frames, size, presets, timings, "orbslam3" in systems
        )
    vocabs = {s.name: vocabulary(out, s, args.force) for s in seqs} if "orbslam3" in systems else {}

    jobs = [(seq, stride, system) for seq in seqs for stride in strides for system in systems]
    cells: dict[tuple[str, int], dict] = {}
    for seq, stride, system in tqdm(jobs, desc="cells", unit="cell", file=sys.stderr):
        run_dir = out / "runs" / slug(seq.name) / f"stride{stride}" / system
        cmd = cell_command(
            seq, stride, system, args.repeats, run_dir, vocabs.get(seq.name), args.override
        )
        slot = cells.setdefault((seq.name, stride), {})
        if args.force or not finished(run_dir, args.repeats):
            run_dir.parent.mkdir(parents=True, exist_ok=True)
            try:
                run_tool(cmd, f"uss-slam {seq.name} stride {stride} {system}")
            except TableError as err:
                slot[system] = {"error": str(err), "command": cmd}
                continue
        slot[system] = cell_figures(run_dir) | {"command": cmd}

    rows = build_rows(seqs, strides, cells)
    meta = {
        "command": command,
        "commit": git_commit(),
        "machine": cpu_model(flags=True),
        "cpus": os.cpu_count(),
        "load_average_start": load_start,
        "load_average_end": os.getloadavg(),
        "repeats": args.repeats,
        "overrides": args.override,
        "strides": strides,
        "systems": systems,
        "synthetic": {"presets": presets, "timings": timings,
                      "frames": args.synthetic_frames, "size": size,
                      "seed": SYNTHETIC_SEED, "vocabulary_seed": VOCAB_SEED}
        if args.synthetic else None,
        "camera_real": args.camera if args.real else None,
    }  # fmt: skip
    table = markdown(rows, systems, meta)
    (out / "table.md").write_text(table)
    (out / "table.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2) + "\n")
    print(json.dumps({"meta": meta, "rows": rows}, indent=2) if args.json else table, end="")
    failed = sum("error" in c for r in rows for c in r["systems"].values())
    if failed:
        print(f"slam_table: error: {failed} cell(s) failed (see table.json)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
