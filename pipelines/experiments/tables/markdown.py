"""Markdown pieces the tables share: metric labels, number formats and the table itself."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from .runs_csv import RATES

LABELS = {
    "mIoU": "mIoU",
    "val_mIoU": "val mIoU",
    **{f"person_{r}": f"person {r}" for r in RATES},
    "ate_rmse": "ATE RMSE [m]",
    "ate_mean": "ATE mean [m]",
    "ate_median": "ATE median [m]",
    "ate_std": "ATE S.D. [m]",
}


def pct(value: float | None) -> str:
    return "—" if value is None else f"{value:.2f}%"


def digits(key: str) -> int:
    return 4 if key.startswith("ate_") else 3


def md_table(header: Sequence[str], body: Iterable[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cells) + " |" for cells in body]
    return lines


def value_text(value: float | None) -> str:
    return "—" if value is None else f"{value:.3f}"


def points_text(value: float | None) -> str:
    return "—" if value is None else f"{value:+.2f}"
