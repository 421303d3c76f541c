"""Every job that failed, was blocked by a failed job, or left no result, and why."""

from __future__ import annotations

from typing import Any

from .markdown import md_table
from .runs_csv import STATUSES


def table_failures(rows) -> tuple[list[dict[str, Any]], list[str]]:
    # an "ok" row with a reason: its rerun failed and the earlier result was kept
    bad = [r for r in rows if r["status"] != "ok" or r.get("reason")]
    data = [{"id": r["id"], "status": r["status"], "reason": r.get("reason") or ""} for r in bad]
    seen: set[str] = set()
    body = []
    for r in bad:  # segeval jobs have one row per sequence: list each job once
        if r["id"] in seen:
            continue
        seen.add(r["id"])
        body.append([f"`{r['id']}`", r["status"], (r.get("reason") or "").replace("|", "\\|")])
    lines = ["### Failures", ""]
    if not body:
        return data, [*lines, "Every job succeeded.", ""]
    counts = {s: len({r["id"] for r in bad if r["status"] == s}) for s in STATUSES[1:]}
    counts["rerun failed (earlier result kept)"] = len(
        {r["id"] for r in bad if r["status"] == "ok"}
    )
    lines += [
        ", ".join(f"{n} {s}" for s, n in counts.items() if n) + " (blocked = an earlier job "
        "it needs failed; missing = the job left no result: killed or interrupted).",
        "",
    ]
    return data, [*lines, *md_table(["job", "status", "reason"], body), ""]
