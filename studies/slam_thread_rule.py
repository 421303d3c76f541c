"""A pre-registered rule on the semantic thread's cells: does a candidate setting (its thread
cells) pass against today's (the same command without it), sequence by sequence? Recorded in
docs/results/slam.md (each entry states its rule before its runs).

Reads the ``cells.json`` that ``studies/slam_semantic_thread.py`` writes in each ``--out``
folder (today's thread cells, the candidate's under ``--label``, and the per-frame cells), or a
CSV this script wrote (``--csv``: one row per repeat, the figures an entry commits), and prints
one row per sequence: today's and the candidate's ATE RMSE median (min–max) and tracked share of
each repeat, their ratio, the candidate's worst repeat against its limit, per-frame masks and
the thread / per-frame ratios (the target ×1.10). The rule, per set of sequences:

- (a) no sequence's ratio (candidate median / today's median) above ``--ratio-cap``;
- (b) the median of the sequences' ratios at most ``--median-cap``;
- (c) no candidate repeat above ``--worst`` × today's worst repeat in that sequence;
- (d) every candidate repeat's tracked share at least today's lowest repeat's less
  ``--tracked-slack`` (a share of frames).

    python studies/slam_thread_rule.py OUT [OUT ...] --today "thread 0.5 s" \\
        --candidate "thread 0.5 s age1" --write-csv docs/results/slam_thread_age/decision.csv
    python studies/slam_thread_rule.py --csv docs/results/slam_thread_age/decision.csv \\
        --today "thread 0.5 s" --candidate "thread 0.5 s age1"

Without ``--today`` / ``--candidate`` it prints the target's table instead: per sequence and
thread cell, the median ATE ÷ per-frame masks' median (the target: ≤ ×1.10) and each repeat's
tracked share, and per cell how many sequences are within ×1.10 (a report, no rule).
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
from pathlib import Path

FIELDS = ("sequence", "cell", "repeat", "ate_rmse", "tracked_fraction")


def read_cells(folders: list[Path]) -> list[dict]:
    """One row per repeat of every cell in each folder's ``cells.json``."""
    rows = []
    for folder in folders:
        record = folder / "cells.json"
        if not record.is_file():
            sys.exit(f"slam_thread_rule: {record}: no such file (run slam_semantic_thread.py)")
        for sequence, cells in json.loads(record.read_text()).items():
            for cell, figures in cells.items():
                pairs = zip(figures["ate_repeats"], figures["tracked_repeats"], strict=True)
                for i, (ate, tracked) in enumerate(pairs):
                    rows.append(dict(zip(FIELDS, (sequence, cell, i, ate, tracked), strict=True)))
    return rows


def read_csv(path: Path) -> list[dict]:
    """The rows :func:`write_csv` wrote."""
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        if reader.fieldnames is None or tuple(reader.fieldnames) != FIELDS:
            sys.exit(f"slam_thread_rule: {path}: expected the columns {','.join(FIELDS)}")
        return [
            {**r, "repeat": int(r["repeat"]), "ate_rmse": float(r["ate_rmse"]),
             "tracked_fraction": float(r["tracked_fraction"])}
            for r in reader
        ]  # fmt: skip


def write_csv(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def cell(rows: list[dict], sequence: str, name: str) -> tuple[list[float], list[float]] | None:
    """The ATE RMSE and tracked share of each repeat of one cell, or None if it did not run."""
    mine = sorted((r for r in rows if r["sequence"] == sequence and r["cell"] == name),
                  key=lambda r: r["repeat"])  # fmt: skip
    if not mine:
        return None
    return [r["ate_rmse"] for r in mine], [r["tracked_fraction"] for r in mine]


def judge(rows: list[dict], today: str, candidate: str, args: argparse.Namespace) -> list[dict]:
    """Per sequence with both cells: the figures of the rule and of the target."""
    out = []
    for sequence in sorted({r["sequence"] for r in rows}):
        a, b = cell(rows, sequence, today), cell(rows, sequence, candidate)
        if a is None or b is None:
            continue
        ref = cell(rows, sequence, "per-frame")
        ratio = statistics.median(b[0]) / statistics.median(a[0])
        limit = args.worst * max(a[0])
        floor = min(a[1]) - args.tracked_slack
        out.append({
            "sequence": sequence, "today": a, "candidate": b, "ratio": ratio, "limit": limit,
            "floor": floor, "per_frame": ref,
            "a": ratio <= args.ratio_cap, "c": max(b[0]) <= limit, "d": min(b[1]) >= floor - 1e-9,
        })  # fmt: skip
    return out


def _cell_text(figures: tuple[list[float], list[float]]) -> str:
    ate, tracked = figures
    shares = " / ".join(f"{100 * t:.1f}" for t in tracked)
    return f"{statistics.median(ate):.4f} ({min(ate):.4f}–{max(ate):.4f}), {shares}%"


def table(judged: list[dict]) -> list[str]:
    lines = [
        "| sequence | today [m] (min–max), tracked % | candidate [m] (min–max), tracked % | "
        "ratio | candidate's worst repeat (limit) | per-frame [m] (min–max), tracked % | "
        "/ per-frame, today → candidate |",
        "|---|---|---|---|---|---|---|",
    ]
    for j in judged:
        ref = j["per_frame"]
        if ref is None:
            pf, vs = "—", "—"
        else:
            m = statistics.median(ref[0])
            pf = _cell_text(ref)
            vs = (f"×{statistics.median(j['today'][0]) / m:.2f} → "
                  f"×{statistics.median(j['candidate'][0]) / m:.2f}")  # fmt: skip
        lines.append(
            f"| {j['sequence']} | {_cell_text(j['today'])} | {_cell_text(j['candidate'])} | "
            f"×{j['ratio']:.3f} | {max(j['candidate'][0]):.4f} ({j['limit']:.4f}) | {pf} | {vs} |"
        )
    return lines


def verdict(judged: list[dict], args: argparse.Namespace) -> tuple[bool, list[str]]:
    """Whether the set passes, and one line per condition."""
    if not judged:
        return False, ["no sequence has both cells"]
    med = statistics.median(j["ratio"] for j in judged)
    fails = {k: [j["sequence"] for j in judged if not j[k]] for k in "acd"}
    lines = [
        f"(a) no ratio above ×{args.ratio_cap:.2f}: "
        + ("met" if not fails["a"] else "failed by " + ", ".join(fails["a"])),
        f"(b) median ratio ×{med:.3f} ≤ ×{args.median_cap:.2f}: " + ("met" if med <= args.median_cap else "failed"),
        f"(c) every repeat ≤ {args.worst:g} × today's worst: "
        + ("met" if not fails["c"] else "failed by " + ", ".join(fails["c"])),
        f"(d) every repeat's tracked share ≥ today's lowest − {100 * args.tracked_slack:g} points: "
        + ("met" if not fails["d"] else "failed by " + ", ".join(fails["d"])),
    ]  # fmt: skip
    passed = med <= args.median_cap and not any(fails.values())
    return passed, lines


TARGET = 1.10
"""The target: the thread's median ATE within this factor of per-frame masks'."""


def _latency_first(name: str) -> tuple[float, str]:
    """Thread cells by their latency (``thread L s ...``), then by name."""
    words = name.split()
    try:
        return float(words[1]), name
    except (IndexError, ValueError):
        return float("inf"), name


def target_table(rows: list[dict]) -> list[str]:
    """Per sequence and thread cell: median ATE ÷ the per-frame median and each repeat's
    tracked share (both cells'); then per cell the sequences within :data:`TARGET`."""
    names = sorted({r["cell"] for r in rows} - {"per-frame"}, key=_latency_first)
    lines = ["| sequence | per-frame [m], tracked % | " + " | ".join(names) + " |",
             "|---" * (len(names) + 2) + "|"]  # fmt: skip
    within = dict.fromkeys(names, 0)
    sequences = sorted({r["sequence"] for r in rows})
    for sequence in sequences:
        ref = cell(rows, sequence, "per-frame")
        if ref is None:
            continue
        m = statistics.median(ref[0])
        cells = []
        for name in names:
            got = cell(rows, sequence, name)
            if got is None:
                cells.append("—")
                continue
            ratio = statistics.median(got[0]) / m
            within[name] += ratio <= TARGET
            shares = " / ".join(f"{100 * t:.0f}" for t in got[1])
            cells.append(f"×{ratio:.2f} ({shares}%)")
        lines.append(f"| {sequence} | {_cell_text(ref)} | " + " | ".join(cells) + " |")
    lines.append("")
    lines += [f"{name}: {within[name]} of {len(sequences)} within ×{TARGET:.2f}" for name in names]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=" ".join(__doc__.split("\n\n")[0].split()),
        epilog="Without --today and --candidate: the target's table (thread ÷ per-frame masks).",
    )
    parser.add_argument("folders", type=Path, nargs="*", help="slam_semantic_thread.py --out")
    parser.add_argument("--csv", type=Path, help="read the repeats from this CSV instead")
    parser.add_argument("--write-csv", type=Path, help="write the repeats read to this CSV")
    parser.add_argument("--today", help="today's thread cell, e.g. 'thread 0.5 s'")
    parser.add_argument("--candidate", help="the candidate's thread cell")
    parser.add_argument(
        "--ratio-cap", type=float, default=1.05, help="(a): no sequence's ratio above this"
    )
    parser.add_argument(
        "--median-cap", type=float, default=1.00, help="(b): the median ratio at most this"
    )
    parser.add_argument(
        "--worst", type=float, default=1.5, help="(c): no repeat above this × today's worst"
    )
    parser.add_argument(
        "--tracked-slack",
        type=float,
        default=0.02,
        help="(d): tracked share below today's lowest by at most this",
    )
    args = parser.parse_args(argv)
    if (args.csv is None) == (not args.folders):
        parser.error("give the study's folders or --csv, not both")
    rows = read_csv(args.csv) if args.csv else read_cells(args.folders)
    if args.write_csv:
        write_csv(rows, args.write_csv)
    if args.today is None and args.candidate is None:
        print("\n".join(target_table(rows)))
        return 0
    if args.today is None or args.candidate is None:
        parser.error("--today and --candidate go together (neither: the target's table)")
    judged = judge(rows, args.today, args.candidate, args)
    print("\n".join(table(judged)))
    passed, lines = verdict(judged, args)
    print("\n".join(["", *lines, f"the set {'passes' if passed else 'does not pass'}"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
