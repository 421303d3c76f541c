"""Judge a SLAM change on whole tables, not on one cell: two ``studies/slam_table.py`` outputs
(``table.json``, before and after, the same cells) compared cell by cell, with the rules fixed
before the runs: cells with spread <= x1.5 must not decrease, the geometric mean of the medians
(per kind: real, synthetic) must not increase, no cell at strides 1-3 may get a median more than
10% worse, and default / no back end must not exceed 1.02 in more rows than before.

    python studies/slam_table_compare.py BEFORE/table.json AFTER/table.json
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


def cells(path: Path) -> dict[tuple[str, int, str], dict]:
    rows = json.loads(path.read_text())["rows"]
    return {
        (r["sequence"], r["stride"], system): c
        for r in rows
        for system, c in r["systems"].items()
        if "error" not in c and c["ate_rmse_median"] is not None
    }


def back_end_ratios(table: dict, noback: dict) -> dict[tuple[str, int], float]:
    """default / no back end per row of ``table``; a table without the no-back-end column
    (a change to the back end alone cannot move it) takes ``noback``'s cells."""
    out = {}
    for (seq, stride, system), cell in table.items():
        if system != "harness":
            continue
        other = table.get((seq, stride, "harness_noback")) or noback.get(
            (seq, stride, "harness_noback")
        )
        if other is not None:
            out[(seq, stride)] = cell["ate_rmse_median"] / other["ate_rmse_median"]
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("before", type=Path)
    p.add_argument("after", type=Path)
    a = p.parse_args()
    before, after = cells(a.before), cells(a.after)
    keys = sorted(set(before) & set(after))
    print("| sequence | stride | system | before | after | after / before |")
    print("|---|---|---|---|---|---|")
    worse = []
    for key in keys:
        b, c = before[key], after[key]
        r = c["ate_rmse_median"] / b["ate_rmse_median"]
        fmt = "{:.4f} ×{:.2f}"
        print(
            f"| {key[0]} | {key[1]} | {key[2]} | "
            f"{fmt.format(b['ate_rmse_median'], b['spread'])} | "
            f"{fmt.format(c['ate_rmse_median'], c['spread'])} | {r:.3f} |"
        )
        if key[1] <= 3 and r > 1.10:
            worse.append(key)
    print()
    for name, table in (("before", before), ("after", after)):
        ok = sum(table[k]["spread"] <= 1.5 for k in keys)
        print(f"- {name}: {ok}/{len(keys)} cells with spread <= x1.5")
    for name, table in (("before", before), ("after", after)):
        logs = [math.log(table[k]["ate_rmse_median"]) for k in keys]
        print(f"- {name}: geometric mean of the medians {math.exp(sum(logs) / len(logs)):.5f} m")
    print(f"- cells at strides 1-3 more than 10% worse: {len(worse)} {worse or ''}")
    rb, ra = back_end_ratios(before, before), back_end_ratios(after, before)
    common = sorted(set(rb) & set(ra))
    if not common:
        print("- default / no back end: neither table has the no-back-end column")
        return
    print(
        f"- default / no back end > 1.02: before {sum(rb[k] > 1.02 for k in common)}, "
        f"after {sum(ra[k] > 1.02 for k in common)} of {len(common)} rows "
        f"(worst before {max(rb[k] for k in common):.2f}, after {max(ra[k] for k in common):.2f})"
    )


if __name__ == "__main__":
    main()
