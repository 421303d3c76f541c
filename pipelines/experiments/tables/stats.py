"""The statistics the tables share: a cell over seeds (:class:`Stat`, :class:`SeedValues`),
the paper's improvement %, differences in points, closure, the downstream ratio, paired
intervals and the smallest effect a paired design can detect (:func:`mde`)."""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from .runs_csv import ATE_KEYS

LOWER_IS_BETTER = {"person_FPR", "person_FNR", "person_PWC", *ATE_KEYS}


@dataclass(frozen=True)
class Stat:
    """A table cell: the values of the successful jobs, and how many jobs gave none."""

    values: tuple[float, ...]
    failed: int = 0  # jobs failed, blocked or without a result
    undefined: int = 0  # jobs that succeeded without a value for this metric

    @property
    def n(self) -> int:
        return len(self.values)

    @property
    def mean(self) -> float | None:
        return statistics.fmean(self.values) if self.values else None

    @property
    def sd(self) -> float | None:
        """Sample standard deviation (``n − 1``); None for fewer than two values."""
        return statistics.stdev(self.values) if len(self.values) > 1 else None

    @property
    def se(self) -> float | None:
        """Standard error of the mean (``s.d. / √n``); None for fewer than two values."""
        sd = self.sd
        return None if sd is None else sd / math.sqrt(self.n)

    def text(self, digits: int = 4, spread: str = "sd") -> str:
        """``mean ± s.d. (n=k)`` (``spread="se"``: ± the standard error), with how many jobs
        failed or gave no value."""
        notes = [f"{self.failed} failed"] if self.failed else []
        notes += [f"{self.undefined} n/a"] if self.undefined else []
        if not self.values:
            if self.failed:
                return "failed" + (f" ({self.failed})" if self.failed > 1 else "")
            return "n/a" if self.undefined else "—"
        body = f"{self.mean:.{digits}f}"
        width = self.se if spread == "se" else self.sd
        if width is not None:
            body += f" ± {width:.{digits}f}"
        return f"{body} (n={self.n}{''.join(', ' + n for n in notes)})"

    def as_json(self) -> dict[str, Any]:
        return {
            "mean": self.mean,
            "sd": self.sd,
            "n": self.n,
            "failed": self.failed,
            "undefined": self.undefined,
            "values": list(self.values),
        }


def stat(rows: Iterable[Mapping[str, Any]], key: str) -> Stat:
    """The :class:`Stat` of column ``key`` over ``rows``."""
    values, failed, undefined = [], 0, 0
    for row in rows:
        if row["status"] != "ok":
            failed += 1
        elif row.get(key) is None or (isinstance(row[key], float) and math.isnan(row[key])):
            undefined += 1
        else:
            values.append(float(row[key]))
    return Stat(tuple(values), failed, undefined)


def improvement(without: Stat, with_: Stat, key: str) -> float | None:
    """The paper's improvement % of the means: positive = ``with_`` is better."""
    a, b = without.mean, with_.mean
    if a is None or b is None or a == 0:
        return None
    gain = (a - b) if key in LOWER_IS_BETTER else (b - a)
    return 100.0 * gain / abs(a)


def is_defined(value: Any) -> bool:
    """A cell value that counts: not missing, not NaN."""
    return value is not None and not (isinstance(value, float) and math.isnan(value))


@dataclass(frozen=True)
class SeedValues:
    """One T0 cell: each seed's value, and how many seeds gave none (failed / undefined)."""

    values: Mapping[int, float]
    failed: int = 0
    undefined: int = 0

    @property
    def stat(self) -> Stat:
        ordered = tuple(self.values[s] for s in sorted(self.values))
        return Stat(ordered, self.failed, self.undefined)

    def as_json(self) -> dict[str, Any]:
        s = self.stat
        return {**s.as_json(), "se": s.se, "per_seed": {str(k): v for k, v in self.values.items()}}


def closure(value: float | None, source_only: float | None, oracle: float | None) -> float | None:
    """``(value − source-only) / (oracle − source-only)``: 0 = no better than source-only, 1 =
    as good as the target oracle; None when a value is missing or the oracle is no better than
    source-only (the ratio is then meaningless)."""
    if value is None or source_only is None or oracle is None or oracle - source_only <= 0:
        return None
    return (value - source_only) / (oracle - source_only)


def paired_closure(row: SeedValues, source_only: SeedValues, oracle: SeedValues) -> SeedValues:
    """The closure of each seed of ``row`` against source-only and the oracle of the *same*
    seed; a seed without all three (or whose oracle is no better) is undefined."""
    values: dict[int, float] = {}
    undefined = 0
    for seed, value in row.values.items():
        c = closure(value, source_only.values.get(seed), oracle.values.get(seed))
        if c is None:
            undefined += 1
        else:
            values[seed] = c
    return SeedValues(values, row.failed, row.undefined + undefined)


def points(stat_: Stat, reference: Stat) -> float | None:
    """The difference of the means in points (100 × the difference of two rates / IoUs)."""
    if stat_.mean is None or reference.mean is None:
        return None
    return 100.0 * (stat_.mean - reference.mean)


def downstream_ratio(none: float | None, model: float | None, oracle: float | None) -> float | None:
    """``(none − model) / (none − oracle)``; None when a value is missing or the oracle is no
    better than no filter (the ratio is then meaningless)."""
    if none is None or model is None or oracle is None or none - oracle <= 0:
        return None
    return (none - model) / (none - oracle)


MDE_ALPHA = 0.05
MDE_POWER = 0.8
MDE_FORMULA = (
    "MDE = (t_{0.975, n−1} + t_{0.80, n−1}) · s / √n: the smallest true mean difference a paired "
    "two-sided Student-t test at α = 0.05 detects with power 0.8 over n seeds, s the sample s.d. "
    "of the paired values (— below two seeds)"
)
"""The footnote of every table that prints an :func:`mde`."""


def mde(sd: float | None, n: int) -> float | None:
    """The minimum detectable effect of a paired two-sided Student-t test at ``MDE_ALPHA`` with
    power ``MDE_POWER`` over ``n`` paired values of sample standard deviation ``sd``:
    ``(t_{1−α/2, n−1} + t_{power, n−1}) · sd / √n`` (in the values' unit); None below two values
    or without ``sd``."""
    if n < 2 or sd is None:
        return None
    from scipy.stats import t

    quantiles = t.ppf(1 - MDE_ALPHA / 2, n - 1) + t.ppf(MDE_POWER, n - 1)
    return float(quantiles * sd / math.sqrt(n))


def mde_text(value: float | None, digits: int = 2) -> str:
    """``MDE 0.12`` (``MDE —`` when there is none)."""
    return "MDE —" if value is None else f"MDE {value:.{digits}f}"


def paired_interval(diffs: Sequence[float], level: float = 0.95) -> dict[str, Any]:
    """Paired differences: each value, how many are positive, their mean and its Student-t
    interval at ``level`` (None below two values), and the minimum detectable effect of the
    comparison (:func:`mde`; None below two values)."""
    out: dict[str, Any] = {"values": list(diffs), "positive": sum(d > 0 for d in diffs),
                           "n": len(diffs), "mean": None, "interval": None,
                           "mde": None}  # fmt: skip
    if diffs:
        out["mean"] = statistics.fmean(diffs)
    if len(diffs) >= 2:
        from scipy.stats import t

        sd = statistics.stdev(diffs)
        half = t.ppf(0.5 + level / 2, len(diffs) - 1) * sd / len(diffs) ** 0.5
        out["interval"] = [out["mean"] - half, out["mean"] + half]
        out["mde"] = mde(sd, len(diffs))
    return out


def paired_text(paired: Mapping[str, Any], with_mde: bool = False) -> str:
    """``+0.12 / +0.30 (2/2 > 0), mean +0.21 [-0.93, +1.35]`` of a :func:`paired_interval`;
    ``with_mde``: then ``, MDE 0.45`` (``, MDE —`` below two values)."""
    if not paired["n"]:
        return "—"
    each = " / ".join(f"{d:+.2f}" for d in paired["values"])
    text = f"{each} ({paired['positive']}/{paired['n']} > 0)"
    if paired["interval"] is not None:
        lo, hi = paired["interval"]
        text += f", mean {paired['mean']:+.2f} [{lo:+.2f}, {hi:+.2f}]"
    if with_mde:
        text += ", " + mde_text(paired.get("mde"))
    return text
