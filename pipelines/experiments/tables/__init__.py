"""The paper's tables from ``runs.csv`` (one row per job of the grid): mean ± s.d. over seeds.

- **T0** the standard UDA table: source-only, AdaBN, each method and the target oracle, each
  with its source validation mIoU (in domain), target mIoU, person IoU and person-mask frame
  metrics (means over the evaluation sequences) and its closure ``(row − source-only) /
  (oracle − source-only)`` paired by seed; mean ± s.e. over seeds and every seed's value;
- **T1** discriminator depth: target mIoU and per-class IoU of every configuration (source-only,
  adapted with n = 4..7), and its ATE RMSE per sequence (semantic filter);
- **T2** "ATL" (with / without adversarial transfer learning): per sequence, mIoU, the person-mask
  frame metrics (FPR, FNR, recall, precision, PWC) and ATE RMSE / mean / median / S.D. of
  source-only against adapted, with the improvement % the paper prints
  (``(without − with) / without`` for errors, ``(with − without) / without`` for scores);
- **T3** "MVG" (with / without multi-view geometry): semantic against semantic+geometry (and
  +object) of the adapted model, with the improvement %;
- baselines (no filter, geometry alone, ground-truth masks) and the downstream ratio
  ``(ATE_none − ATE_model) / (ATE_none − ATE_oracle)`` per sequence and seed (1 = as good as
  ground-truth masks, 0 = no better than no filter);
- failures: every job that failed, was blocked by a failed job, or left no result, and why.

Each cell is ``mean ± s.d. (n=k)`` over the seeds whose job succeeded (sample s.d., ``n − 1``);
a cell with failed jobs says how many (``n=2, 1 failed``); a cell with none says ``failed``.
Beside every paired comparison over seeds (T0's closures, T0's paired differences of each row to
source-only and to AdaBN, the downstream ratio's differences to source-only) stands its minimum
detectable effect (:func:`~.stats.mde`). Every model chosen with
target labels (the oracle's training, a shift preset's method settings, a checkpoint policy that
reads them: ``runs.csv``'s ``target_labels``) is marked † in each table that shows it.
Pure Python + numpy (matplotlib for the plots only).

One module each: :mod:`.runs_csv` (the rows), :mod:`.stats` (the statistics the tables share),
:mod:`.layout` (what the tables show), :mod:`.markdown`, one module per table or small family
(:mod:`.t0`, :mod:`.t1`, :mod:`.t2`, :mod:`.t3`, :mod:`.crf`, :mod:`.baselines`, :mod:`.ratio`,
:mod:`.timing`, :mod:`.failures`), :mod:`.plots`, and :mod:`.report` (every table at once).
"""

from __future__ import annotations

from .baselines import BASELINES, table_baselines
from .crf import CRF_PAIRS, table_crf
from .failures import table_failures
from .layout import DAGGER_NOTE, Layout, layout_from_rows, target_label_uses
from .markdown import LABELS
from .plots import write_plots
from .ratio import RATIO_FILTERS, table_ratio
from .report import compute, write_tables
from .runs_csv import (
    ALL_SEQUENCES,
    ATE_KEYS,
    COLUMNS,
    INT_COLUMNS,
    RATES,
    REPEAT_COLUMNS,
    SOURCE_VAL,
    STATUSES,
    TEXT_COLUMNS,
    TIMING_COLUMNS,
    read_runs,
    write_runs,
)
from .stats import (
    LOWER_IS_BETTER,
    MDE_FORMULA,
    SeedValues,
    Stat,
    closure,
    downstream_ratio,
    improvement,
    mde,
    mde_text,
    paired_closure,
    paired_interval,
    paired_text,
    points,
    stat,
)
from .t0 import T0_FRAMES, T0_SEG, seed_means, t0_rows, table_t0, target_labels
from .t1 import table_t1
from .t2 import T2_SEG, table_methods, table_t2
from .t3 import table_t3
from .timing import table_timing

__all__ = [
    "ALL_SEQUENCES",
    "ATE_KEYS",
    "BASELINES",
    "COLUMNS",
    "CRF_PAIRS",
    "DAGGER_NOTE",
    "INT_COLUMNS",
    "LABELS",
    "LOWER_IS_BETTER",
    "MDE_FORMULA",
    "RATES",
    "RATIO_FILTERS",
    "REPEAT_COLUMNS",
    "SOURCE_VAL",
    "STATUSES",
    "T0_FRAMES",
    "T0_SEG",
    "T2_SEG",
    "TEXT_COLUMNS",
    "TIMING_COLUMNS",
    "Layout",
    "SeedValues",
    "Stat",
    "closure",
    "compute",
    "downstream_ratio",
    "improvement",
    "layout_from_rows",
    "mde",
    "mde_text",
    "paired_closure",
    "paired_interval",
    "paired_text",
    "points",
    "read_runs",
    "seed_means",
    "stat",
    "t0_rows",
    "table_baselines",
    "table_crf",
    "table_failures",
    "table_methods",
    "table_ratio",
    "table_t0",
    "table_t1",
    "table_t2",
    "table_t3",
    "table_timing",
    "target_label_uses",
    "target_labels",
    "write_plots",
    "write_runs",
    "write_tables",
]
