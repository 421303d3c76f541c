"""studies/gap_study.py and studies/gap_figures.py on fake files: the bad inputs (a read
evaluation seed, a study whose rows differ in init or budget, a missing render), the
discriminator log's blocks, and the figures recomputed from a confusion CSV (paired across
renders, the render / seed variance split, the closure, the D-at-chance mark)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml
from shared_helpers import write_csv

from uss_slam.testing.scripts import load_script

ROOT = Path(__file__).resolve().parents[2] / "studies"
study = load_script(ROOT / "gap_study.py")
figures = load_script(ROOT / "gap_figures.py")


def _training(folder: Path, name: str, weights: str = "/i/init.ckpt", iters: int = 300) -> None:
    hydra = folder / "train" / name / ".hydra"
    hydra.mkdir(parents=True)
    cfg = {"model": {"net": {"weights_path": weights}, "max_iters": iters,
                     "optimizer": {"lr": 0.0025}}}  # fmt: skip
    (hydra / "config.yaml").write_text(yaml.safe_dump(cfg))


def test_a_study_with_another_init_or_budget_is_one_line_naming_the_file(tmp_path: Path) -> None:
    _training(tmp_path, "source_only_s0")
    _training(tmp_path, "adaptsegnet_s0")
    assert study.check_study(tmp_path)["trainings"] == 2
    _training(tmp_path, "oracle_s0", iters=1200)
    with pytest.raises(SystemExit, match=r"oracle_s0/\.hydra/config\.yaml: model\.max_iters=1200"):
        study.check_study(tmp_path)
    other = tmp_path / "b"
    _training(other, "a_s0")
    _training(other, "b_s0", weights="/j/init.ckpt")
    with pytest.raises(SystemExit, match=r"model\.net\.weights_path=/j/init\.ckpt, but "):
        study.check_study(other)


def test_an_evaluation_seed_read_by_another_study_is_refused(tmp_path: Path) -> None:
    read = tmp_path / "read.csv"
    study.mark_read([7100, 7101], "warm_start", read)
    study.check_unread([8300, 8301], "real_regime", read)  # unread: fine
    with pytest.raises(SystemExit, match=r"read\.csv: evaluation render seed\(s\) 7101 already "
                                          r"read by warm_start"):  # fmt: skip
        study.check_unread([7101, 8300], "real_regime", read)
    study.mark_read([8300, 7101], "real_regime", read)
    assert study.read_list(read) == {7100: "warm_start", 7101: "warm_start", 8300: "real_regime"}
    study.check_unread([8300], "real_regime", read)  # its own study may score again


def test_blocks_and_renders(tmp_path: Path) -> None:
    assert study.parse_blocks("8100,8200") == [8100, 8200]
    for bad in ("8100,8100", "x", ""):
        with pytest.raises(SystemExit, match="--blocks"):
            study.parse_blocks(bad)
    for i, preset in enumerate(study.PRESETS):
        (tmp_path / f"{preset}_{8100 + i}" / "labels").mkdir(parents=True)
        (tmp_path / f"{preset}_{8100 + i}" / "rgb.txt").write_text("# x\n1.0 rgb/1.0.png\n")
    found = study.render_folders(tmp_path, [8100])
    assert [(p, s) for p, _, s, _ in found] == [
        ("walking_xyz", 8100),
        ("walking_rpy", 8101),
        ("walking_halfsphere", 8102),
    ]
    with pytest.raises(SystemExit, match=r"walking_xyz_8200: no render"):
        study.render_folders(tmp_path, [8200])


def test_dacc_in_blocks_per_head(tmp_path: Path) -> None:
    log = tmp_path / "train" / "adaptsegnet_n5_bnreference_s3" / "csv" / "metrics.csv"
    log.parent.mkdir(parents=True)
    with open(log, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "train/d_acc_main", "train/d_acc_aux", "val/mIoU"])
        for step in range(50):
            w.writerow([step, 0.5 if step < 25 else 0.9, 0.5, ""])
        w.writerow([50, "", "", 0.4])  # a validation row: no accuracy
    rows = study.dacc(tmp_path)
    main = [(r["step"], r["d_acc"]) for r in rows if r["head"] == "main"]
    assert main == [(25, 0.5), (50, 0.9)]
    assert rows[0]["row"] == "adaptsegnet_n5_bnreference" and rows[0]["seed"] == "3"


def _matrix(person: float) -> dict[str, int]:
    hit = round(1000 * person)
    m = np.diag([1000, hit, 1000, 1000])
    m[1, 0] = 1000 - hit
    return {f"c{t}{p}": int(m[t, p]) for t in range(4) for p in range(4)}


def test_figures_pair_across_renders_and_split_the_variance(tmp_path: Path) -> None:
    rows = []
    render_effect = {8300: 0.0, 8400: 0.1, 8500: 0.2}
    for block, effect in render_effect.items():
        for seed in range(3):
            for row, base in (("source_only_bntrained", 0.3), ("adabn_bntrained", 0.4),
                              ("oracle", 0.7)):  # fmt: skip
                # the gain over source-only grows with the render, not with the seed
                value = base + (effect if row == "adabn_bntrained" else 0.0) + 0.001 * seed
                rows.append({"role": "eval", "model": f"{row}_s{seed}", "row": row,
                             "seed": str(seed), "preset": "walking_xyz", "block": block,
                             "render_seed": block, "frames": 1, **_matrix(value)})  # fmt: skip
        rows.append({"role": "eval", "model": "init", "row": "init", "seed": "",
                     "preset": "walking_xyz", "block": block, "render_seed": block, "frames": 1,
                     **_matrix(0.2)})  # fmt: skip
    path = tmp_path / "confusion.csv"
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    scores = figures.read_scores(path, "eval")
    p = figures.paired(scores, "adabn_bntrained", "source_only_bntrained", "person")
    assert p["n"] == 3 and p["mean"] == pytest.approx(20.0, abs=0.2)
    split = figures.variance_split(scores["adabn_bntrained"], scores["source_only_bntrained"],
                                   "person")  # fmt: skip
    assert split["render"] > 50 and split["seed"] < 0.01
    # more renders, smaller MDE; more seeds do not help against a render-borne variance
    assert figures.projected_mde(split, 24, 8) < figures.projected_mde(split, 6, 8)
    assert figures.projected_mde(split, 24, 8) == pytest.approx(
        figures.projected_mde(split, 24, 80), rel=0.01
    )
    c = figures.closure(scores, "adabn_bntrained")
    assert c[0] == pytest.approx(20 / 40, abs=0.02)
    text = "\n".join(figures.tables(scores, None))
    assert "headroom: oracle − source_only_bntrained | +40.0 [" in text
    assert (
        "| the init as is | 20.0 [20.0, 20.0] |" in text
    )  # rows without seeds: one value per render
    row = "| adabn_bntrained − source_only_bntrained | walking_xyz | +20.0 | +10 +20 +30 |"
    assert row in text


def test_figures_read_several_files_and_refuse_a_matrix_scored_twice(tmp_path: Path) -> None:
    def write(name: str, rows: list[dict]) -> Path:
        return write_csv(tmp_path / name, rows)

    def row(name: str, seed: int, value: float) -> dict:
        return {"role": "eval", "model": f"{name}_s{seed}", "row": name, "seed": str(seed),
                "preset": "walking_xyz", "block": 8300, "render_seed": 8300, "frames": 1,
                **_matrix(value)}  # fmt: skip

    a = write("a.csv", [row("source_only_bntrained", 0, 0.3)])
    b = write("b.csv", [row("fda_bntrained", 0, 0.4), row("source_only_bntrained", 1, 0.5)])
    scores = figures.read_scores([a, b], "eval")
    assert set(scores["source_only_bntrained"]["walking_xyz_8300"]) == {"0", "1"}
    assert scores["fda_bntrained"]["walking_xyz_8300"]["0"]["person"] == pytest.approx(
        40.0, abs=0.5
    )
    again = write("c.csv", [row("fda_bntrained", 1, 0.4), row("source_only_bntrained", 0, 0.2)])
    with pytest.raises(SystemExit, match=r"c.csv:3: source_only_bntrained_s0 on walking_xyz_8300 "
                       r"is scored already at .*a.csv:2"):  # fmt: skip
        figures.read_scores([a, again], "eval")


def test_d_at_chance_is_marked() -> None:
    lines, marks = figures.dacc_lines(
        {
            "adaptsegnet_n5_bnreference": {
                "0": {"main": [0.5, 0.52], "aux": [0.49, 0.5]},
                "1": {"main": [0.5, 0.8], "aux": [0.5, 0.5]},
            }
        }
    )
    assert marks == {"adaptsegnet_n5_bnreference": "D at chance on 1/2 seeds"}
    assert any(line.endswith("D at chance |") for line in lines)


def test_first_frames_then_every_nth(tmp_path: Path) -> None:
    lines = ["# color images"] + [f"{i}.0 rgb/{i}.png" for i in range(300)]
    (tmp_path / "rgb.txt").write_text("\n".join(lines) + "\n")
    assert study.frame_files(tmp_path, 10, 100) == [f"rgb/{i}.png" for i in range(0, 100, 10)]
    assert len(study.frame_files(tmp_path, 5)) == 60


def test_ate_cost_against_the_unfiltered_run(tmp_path: Path) -> None:
    import json

    for name, med in (("none", 0.005), ("adabn_s0", 0.0065)):
        (tmp_path / name).mkdir()
        metrics = {"ate": {"rmse": med}, "ate_rmse_repeats": {"min": med - 0.001, "max": med}}
        (tmp_path / name / "metrics.json").write_text(json.dumps(metrics))
    rows = {r["model"]: r for r in study.ate_cost(tmp_path)}
    assert rows["adabn_s0"]["ratio_to_none"] == 1.3 and rows["none"]["ratio_to_none"] == 1.0
    with pytest.raises(SystemExit, match=r"/none: no unfiltered run"):
        study.main(["ate-cost", str(tmp_path / "adabn_s0"), "--out", str(tmp_path / "x.csv")])
