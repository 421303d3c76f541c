"""studies/validator_regime.py: a validator's ranking and its pick per seed, from files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from shared_helpers import write_csv

from uss_slam.testing.scripts import load_script

regime = load_script(Path(__file__).resolve().parents[2] / "studies" / "validator_regime.py")

BASE = {"source_only_bntrained": 0.30, "source_only_bnreference": 0.34, "adabn_bntrained": 0.45,
        "adabn_bnreference": 0.44, "adaptsegnet_n5_bnreference": 0.36, "fda_bntrained": 0.28,
        "fda_bntrained_adabn": 0.40, "init": 0.38, "init_adabn": 0.33}  # fmt: skip


def _matrix(person: float) -> dict[str, int]:
    hit = round(1000 * person)
    m = np.diag([1000, hit, 1000, 1000])
    m[1, 0] = 1000 - hit
    return {f"c{t}{p}": int(m[t, p]) for t in range(4) for p in range(4)}


def _study(tmp_path: Path) -> tuple[Path, Path]:
    confusion, validators = [], []
    for row, base in BASE.items():
        for seed in [""] if row in regime.INIT_ROWS else ["0", "1"]:
            model = row + (f"_s{seed}" if seed else "")
            for block, lift in ((8300, 0.0), (8400, 0.05), (8500, 0.1)):
                value = base + lift + (0.01 if seed == "1" else 0.0)
                confusion.append({"role": "eval", "model": model, "row": row, "seed": seed,
                                  "preset": "walking_xyz", "block": block, "render_seed": block,
                                  "frames": 1, **_matrix(value)})  # fmt: skip
            # entropy follows the truth; the probe too (so, lower being better, it inverts it)
            own = base + (0.01 if seed == "1" else 0.0)
            validators.append({"model": model, "row": row, "seed": seed, "entropy": own,
                               "im": 0.1, "snd": 1.0 - base, "probe": own,
                               "dynamic_share": 0.2})  # fmt: skip
    return write_csv(tmp_path / "v.csv", validators), write_csv(tmp_path / "c.csv", confusion)


def test_a_validator_that_follows_the_truth_ranks_and_picks_as_the_labels_do(tmp_path) -> None:
    v, c = _study(tmp_path)
    lines = regime.figures(regime.read_validators(v), regime.gap_figures.read_scores([c], "eval"))
    table = {}
    for line in lines:
        if line.startswith("| "):
            cells = [c.strip() for c in line.strip("|").split("|")]
            table[cells[0]] = cells
    assert "Models: 16 (seeds 0, 1)" in lines[0]
    assert table["entropy"][1] == "+1.00"
    assert float(table["probe"][1]) < -0.5  # lower is better: the inverse ranking
    # entropy picks AdaBN in both seeds, as the labels do; the gain over continued source-only
    assert table["entropy"][4] == "adabn_bntrained: 0,1"
    assert table["entropy"][2] == table["labels' pick †"][2]
    assert table["always AdaBN"][2].startswith("+")
    assert table["always AdaBN"][3] == "+0.0 [+0.0, +0.0]"  # AdaBN against itself
    assert table["snd"][3].startswith("-")
    assert table["snd"][4] == "fda_bntrained: 0,1"  # 1 − base: the worst row


def test_a_validator_file_without_a_number_names_its_line(tmp_path: Path) -> None:
    path = write_csv(tmp_path / "v.csv", [{"model": "init", "row": "init", "seed": "",
                                        "entropy": "x", "im": 1, "snd": 1, "probe": 1,
                                        "dynamic_share": 1}])  # fmt: skip
    with pytest.raises(SystemExit, match=r"v.csv:2: expected a number"):
        regime.read_validators(path)
