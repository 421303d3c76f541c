"""``uss-eval compare --slam``: the SLAM harness on every compared sequence, without a filter and
with each model's semantic filter, ``--repeats`` runs per row, and one rule for "separated".

A row is the median ATE RMSE of its repeats with their range ``[min, max]``; two rows are
*separated* only when their ranges do not overlap (:func:`~uss_slam.core.verdict.separated`;
touching counts as overlapping), the same rule for every pair and every sequence. On a sequence
the user marks static (``--static NAME``: nothing moves in it), a filter can only cost: the
report gives each model's ATE minus the unfiltered ATE there, and whether that is separated.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uss_slam.core.errors import UssSlamError
from uss_slam.core.verdict import separated

from .compare import ComparePlan


@dataclass(frozen=True)
class SlamPlan:
    roots: dict[str, Path]  # sequence name -> folder (every compared sequence)
    static: tuple[str, ...]
    repeats: int


def check_slam(plan: ComparePlan, roots: list[Path], static: list[str], repeats: int) -> SlamPlan:
    """``--slam``'s inputs, checked before any work: ground truth and depth in every sequence,
    each ``--static`` name one of the compared sequences, ``--repeats`` >= 2 (a range needs two)."""
    from uss_slam.core.tum_io import read_trajectory, read_tum_folder

    if repeats < 2:
        raise UssSlamError(
            f"--repeats: expected an integer >= 2 (a range needs two runs), got {repeats}"
        )
    named = dict(zip(plan.sequences, roots, strict=True))
    for name in static:
        if name not in named:
            raise UssSlamError(
                f"--static {name}: not a compared sequence; expected one of {', '.join(named)}"
            )
    for root in roots:
        read_tum_folder(root, depth=True)  # depth.txt and its association: errors name the file
        gt = root / "groundtruth.txt"
        if not gt.is_file():
            raise UssSlamError(f"{gt}: not found (--slam reports ATE against the ground truth)")
        if len(read_trajectory(gt)) < 2:
            raise UssSlamError(f"{gt}: expected at least 2 poses 'timestamp tx ty tz qx qy qz qw'")
    return SlamPlan(named, tuple(static), repeats)


def run_slam_rows(plan: ComparePlan, slam: SlamPlan, out: Path) -> dict[str, list[dict[str, Any]]]:
    """Per sequence, the rows ``no filter`` and ``<model> semantic`` (run into
    ``out/slam/<sequence>/<row>/``): ``{row, median, min, max}`` ATE RMSE in metres."""
    from uss_slam.pipelines.runs import Segmenter, SlamJob, run_slam

    rows: dict[str, list[dict[str, Any]]] = {}
    for name, root in slam.roots.items():
        jobs = {
            "no filter": SlamJob(root, Segmenter("none"), (), (f"slam.repeats={slam.repeats}",))
        }
        for m in plan.models:
            jobs[m.name] = SlamJob(
                root, Segmenter.onnx(m.path), ("semantic",), (f"slam.repeats={slam.repeats}",)
            )
        rows[name] = []
        for row, job in jobs.items():
            data = run_slam(job, out / "slam" / name.replace("/", "_") / row.replace(" ", "_"))
            spread = data.get("ate_rmse_repeats") or {}
            rows[name].append({"row": row, "median": spread.get("median"), "min": spread.get("min"),
                               "max": spread.get("max")})  # fmt: skip
    return rows


def _range(r: dict[str, Any]) -> tuple[float, float] | None:
    return None if r["min"] is None else (r["min"], r["max"])


def slam_markdown(
    rows: dict[str, list[dict[str, Any]]], static: tuple[str, ...]
) -> tuple[str, list[str]]:
    """The SLAM table (ATE RMSE median [min, max] in cm; separated from no filter?) per sequence,
    and findings (every separated pair; the filter's cost on static sequences)."""
    lines = ["## SLAM (ATE RMSE, cm: median of the repeats [min, max])", "",
             "Two rows are separated only when their ranges do not overlap.", "",
             "| sequence | row | ATE | separated from no filter |", "|---|---|---|---|"]  # fmt: skip
    findings: list[str] = []
    for seq, seq_rows in rows.items():
        base = _range(seq_rows[0])
        for r in seq_rows:
            rng = _range(r)
            ate = (
                "lost"
                if rng is None
                else f"{100 * r['median']:.1f} [{100 * r['min']:.1f}, {100 * r['max']:.1f}]"
            )
            sep = (
                "—"
                if r is seq_rows[0]
                else ("yes" if base and rng and separated(base, rng) else "no")
            )
            lines.append(f"| {seq} | {r['row']} | {ate} | {sep} |")
        models = seq_rows[1:]
        for i, a in enumerate(models):
            for b in models[i + 1 :]:
                ra, rb = _range(a), _range(b)
                if ra and rb and separated(ra, rb):
                    findings.append(f"{seq}: {a['row']} and {b['row']} are separated in ATE "
                                    f"({100 * a['median']:.1f} vs {100 * b['median']:.1f} cm).")  # fmt: skip
        if seq in static and base is not None:
            for r in models:
                rng = _range(r)
                if rng is None:
                    findings.append(f"{seq} (static): {r['row']}'s filter loses tracking.")
                    continue
                cost = 100 * (r["median"] - seq_rows[0]["median"])
                sep = "separated" if separated(base, rng) else "not separated"
                findings.append(
                    f"{seq} (static): {r['row']}'s filter costs {cost:+.1f} cm ATE ({sep})."
                )
    return "\n".join(lines), findings
