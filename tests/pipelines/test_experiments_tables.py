"""The tables of uss-experiments from a small hand-written runs.csv: mean ± s.d. over seeds,
the paper's improvement %, the downstream ratio, failure marking, the runs.csv format, the
minimum detectable effect beside every paired interval and the † of rows chosen with target
labels."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from uss_slam.core.errors import DataFormatError
from uss_slam.pipelines.experiments import tables as tbl

# source-only over seeds 0-2; adapted (n = 5) over seeds 0-1, its seed-2 training failed (so its
# segmentation evaluation and SLAM runs are blocked). One sequence, the harness.
RUNS_CSV = """\
kind,id,status,reason,method,n_layers,config,seed,system,sequence,variant,val_mIoU,mIoU,person_FPR,ate_rmse
train,train/source_only_s0,ok,,source_only,,source_only,0,,,,0.30,,,
train,train/source_only_s1,ok,,source_only,,source_only,1,,,,0.32,,,
train,train/source_only_s2,ok,,source_only,,source_only,2,,,,0.34,,,
train,train/adaptsegnet_n5_s0,ok,,adaptsegnet,5,adaptsegnet_n5,0,,,,0.40,,,
train,train/adaptsegnet_n5_s1,ok,,adaptsegnet,5,adaptsegnet_n5,1,,,,0.44,,,
train,train/adaptsegnet_n5_s2,failed,ValueError: boom,adaptsegnet,5,adaptsegnet_n5,2,,,,,,,
segeval,segeval/source_only_s0,ok,,source_only,,source_only,0,,walking_xyz,,,0.20,0.1,
segeval,segeval/source_only_s0,ok,,source_only,,source_only,0,,all,,,0.20,0.1,
segeval,segeval/source_only_s1,ok,,source_only,,source_only,1,,walking_xyz,,,0.22,0.2,
segeval,segeval/source_only_s1,ok,,source_only,,source_only,1,,all,,,0.22,0.2,
segeval,segeval/source_only_s2,ok,,source_only,,source_only,2,,walking_xyz,,,0.24,0.3,
segeval,segeval/source_only_s2,ok,,source_only,,source_only,2,,all,,,0.24,0.3,
segeval,segeval/adaptsegnet_n5_s0,ok,,adaptsegnet,5,adaptsegnet_n5,0,,walking_xyz,,,0.30,0.05,
segeval,segeval/adaptsegnet_n5_s0,ok,,adaptsegnet,5,adaptsegnet_n5,0,,all,,,0.30,0.05,
segeval,segeval/adaptsegnet_n5_s1,ok,,adaptsegnet,5,adaptsegnet_n5,1,,walking_xyz,,,0.34,0.15,
segeval,segeval/adaptsegnet_n5_s1,ok,,adaptsegnet,5,adaptsegnet_n5,1,,all,,,0.34,0.15,
segeval,segeval/adaptsegnet_n5_s2,blocked,needs exports/adaptsegnet_n5_s2,adaptsegnet,5,adaptsegnet_n5,2,,walking_xyz,,,,,
segeval,segeval/adaptsegnet_n5_s2,blocked,needs exports/adaptsegnet_n5_s2,adaptsegnet,5,adaptsegnet_n5,2,,all,,,,,
slam,slam/harness/walking_xyz/none,ok,,,,,,harness,walking_xyz,none,,,,0.100
slam,slam/harness/walking_xyz/semantic/source_only_s0,ok,,source_only,,source_only,0,harness,walking_xyz,semantic,,,,0.060
slam,slam/harness/walking_xyz/semantic/source_only_s1,ok,,source_only,,source_only,1,harness,walking_xyz,semantic,,,,0.070
slam,slam/harness/walking_xyz/semantic/source_only_s2,ok,,source_only,,source_only,2,harness,walking_xyz,semantic,,,,0.080
slam,slam/harness/walking_xyz/semantic/adaptsegnet_n5_s0,ok,,adaptsegnet,5,adaptsegnet_n5,0,harness,walking_xyz,semantic,,,,0.040
slam,slam/harness/walking_xyz/semantic/adaptsegnet_n5_s1,ok,,adaptsegnet,5,adaptsegnet_n5,1,harness,walking_xyz,semantic,,,,0.047
slam,slam/harness/walking_xyz/semantic/adaptsegnet_n5_s2,blocked,needs exports/adaptsegnet_n5_s2,adaptsegnet,5,adaptsegnet_n5,2,harness,walking_xyz,semantic,,,,
slam,slam/harness/walking_xyz/semantic_geometry/adaptsegnet_n5_s0,ok,,adaptsegnet,5,adaptsegnet_n5,0,harness,walking_xyz,semantic_geometry,,,,0.030
slam,slam/harness/walking_xyz/semantic_geometry/adaptsegnet_n5_s1,ok,,adaptsegnet,5,adaptsegnet_n5,1,harness,walking_xyz,semantic_geometry,,,,0.040
slam,slam/harness/walking_xyz/semantic_geometry/adaptsegnet_n5_s2,blocked,needs exports/adaptsegnet_n5_s2,adaptsegnet,5,adaptsegnet_n5,2,harness,walking_xyz,semantic_geometry,,,,
slam,slam/harness/walking_xyz/oracle,ok,,,,,,harness,walking_xyz,oracle,,,,0.020
"""


@pytest.fixture()
def rows(tmp_path: Path) -> list[dict]:
    path = tmp_path / "runs.csv"
    path.write_text(RUNS_CSV)
    return tbl.read_runs(path)


def test_stat_is_mean_and_sample_sd_with_counts() -> None:
    s = tbl.Stat((0.010, 0.012, 0.014))
    assert s.mean == pytest.approx(0.012) and s.sd == pytest.approx(0.002)  # sqrt(8e-6 / 2)
    assert s.text(4) == "0.0120 ± 0.0020 (n=3)"
    assert tbl.Stat((0.5,), failed=2).text(3) == "0.500 (n=1, 2 failed)"
    assert tbl.Stat((), failed=1).text() == "failed"
    assert tbl.Stat((), failed=3).text() == "failed (3)"
    assert tbl.Stat((), undefined=2).text() == "n/a"
    assert tbl.Stat(()).text() == "—"


def test_read_runs_types_and_empty_cells(rows: list[dict]) -> None:
    assert len(rows) == 29
    first = rows[3]
    assert first["n_layers"] == 5 and isinstance(first["n_layers"], int)
    assert first["val_mIoU"] == 0.40 and first["ate_rmse"] is None and first["reason"] is None


def test_t1_t2_t3_ratio_and_failures(rows: list[dict], tmp_path: Path) -> None:
    data, text = tbl.compute(rows, n_layers=5)
    assert data["layout"]["configs"] == ["source_only", "adaptsegnet_n5"]
    assert data["layout"]["sequences"] == ["walking_xyz"]

    seg = {r["config"]: r for r in data["T1"]["segmentation"]}
    assert seg["source_only"]["val_mIoU"]["mean"] == pytest.approx(0.32)
    assert seg["source_only"]["val_mIoU"]["sd"] == pytest.approx(0.02)
    assert seg["adaptsegnet_n5"]["mIoU"]["values"] == [0.30, 0.34]
    assert seg["adaptsegnet_n5"]["mIoU"]["failed"] == 1
    assert "| source_only | 0.320 ± 0.020 (n=3) | 0.220 ± 0.020 (n=3) |" in text
    assert (
        "| adaptsegnet_n5 | 0.420 ± 0.028 (n=2, 1 failed) | 0.320 ± 0.028 (n=2, 1 failed) |" in text
    )

    t2 = {r["metric"]: r for r in data["T2"]["per_sequence"]}
    ate = t2["ATE RMSE [m] (harness)"]
    assert ate["without"]["mean"] == pytest.approx(0.070) and ate["without"]["sd"] == pytest.approx(
        0.010
    )
    assert ate["with"]["mean"] == pytest.approx(0.0435)
    assert ate["with"]["sd"] == pytest.approx(0.007 / math.sqrt(2))
    assert ate["improvement_pct"] == pytest.approx(100 * (0.070 - 0.0435) / 0.070)  # 37.86
    assert t2["mIoU"]["improvement_pct"] == pytest.approx(100 * (0.32 - 0.22) / 0.22)  # 45.45
    assert t2["person FPR"]["improvement_pct"] == pytest.approx(50.0)  # lower is better
    assert (
        "| ATE RMSE [m] (harness) | 0.0700 ± 0.0100 (n=3) | 0.0435 ± 0.0049 (n=2, 1 failed) "
        "| 37.86% |"
    ) in text
    assert "| mIoU | 0.220 ± 0.020 (n=3) | 0.320 ± 0.028 (n=2, 1 failed) | 45.45% |" in text

    t3 = [r for r in data["T3"]["rows"] if r["metric"] == "ate_rmse"]
    assert len(t3) == 1 and t3[0]["semantic_geometry"]["mean"] == pytest.approx(0.035)
    assert t3[0]["improvement_pct"] == pytest.approx(100 * (0.0435 - 0.035) / 0.0435)  # 19.54
    assert (
        "| walking_xyz | ATE RMSE [m] | 0.0435 ± 0.0049 (n=2, 1 failed) "
        "| 0.0350 ± 0.0071 (n=2, 1 failed) | 19.54% |"
    ) in text

    ratio = {
        (r["config"], r["seed"]): r["ratio"]
        for r in data["downstream_ratio"]
        if r["filter"] == "semantic"
    }
    assert ratio[("source_only", 0)] == pytest.approx((0.1 - 0.06) / (0.1 - 0.02))  # 0.5
    assert ratio[("source_only", 2)] == pytest.approx(0.25)
    assert ratio[("adaptsegnet_n5", 1)] == pytest.approx((0.1 - 0.047) / 0.08)  # 0.6625
    assert ratio[("adaptsegnet_n5", 2)] is None  # blocked
    assert "| source_only | mean ± s.d. | 0.375 ± 0.125 (n=3) |" in text
    assert "| adaptsegnet_n5 | mean ± s.d. | 0.706 ± 0.062 (n=2) |" in text
    assert "| adaptsegnet_n5 | 2 | — |" in text
    assert "| source_only | median | 0.375 |" in text  # of 0.5, 0.25, 0.375
    # paired by seed: 0.75 - 0.5 and 0.6625 - 0.375 (seed 2 has no adapted run), with the
    # Student-t interval of their mean (1 degree of freedom)
    paired = next(r for r in data["downstream_ratio_paired"] if r["filter"] == "semantic")
    assert paired["values"] == pytest.approx([0.25, 0.2875])
    assert (paired["positive"], paired["n"]) == (2, 2)
    half = 12.7062 * math.sqrt(((0.25 - 0.26875) ** 2 + (0.2875 - 0.26875) ** 2) / 1) / math.sqrt(2)
    assert paired["interval"] == pytest.approx([0.26875 - half, 0.26875 + half], abs=1e-4)
    # beside the interval, its minimum detectable effect: (t_0.975,1 + t_0.80,1) · s / √2
    sd = math.sqrt(((0.25 - 0.26875) ** 2 + (0.2875 - 0.26875) ** 2) / 1)
    assert paired["mde"] == pytest.approx((12.7062 + 1.3764) * sd / math.sqrt(2), abs=1e-4)
    assert (
        f"| adaptsegnet_n5 | − source_only | +0.25 / +0.29 (2/2 > 0), mean +0.27 "
        f"[{0.26875 - half:+.2f}, {0.26875 + half:+.2f}], MDE {paired['mde']:.2f} |"
    ) in text
    assert tbl.MDE_FORMULA in text  # the footnote states the formula
    assert tbl.paired_interval([0.1])["interval"] is None
    assert tbl.paired_interval([])["mean"] is None
    assert "| adaptsegnet_n5 | median | 0.706 |" in text  # of two seeds: their mean
    geometry = {
        (r["config"], r["seed"]): r["ratio"]
        for r in data["downstream_ratio"]
        if r["filter"] == "semantic_geometry"
    }
    assert geometry[("adaptsegnet_n5", 0)] == pytest.approx((0.1 - 0.03) / 0.08)
    assert ("source_only", 0) not in geometry  # source-only had no semantic+geometry runs
    block = text.split("#### harness, semantic+geometry")[1].split("###")[0]
    assert (
        "| adaptsegnet_n5 | median | 0.812 |" in block
    )  # of 0.875, 0.75 and "source_only" not in block
    assert "#### harness, semantic+geometry" in text and "#### harness, semantic\n" in text

    assert "| none | oracle |" not in text  # labels, not names
    assert "| walking_xyz | 0.1000 (n=1) | 0.0200 (n=1) |" in text

    failures = {f["id"]: f for f in data["failures"]}
    assert failures["train/adaptsegnet_n5_s2"]["status"] == "failed"
    assert failures["train/adaptsegnet_n5_s2"]["reason"] == "ValueError: boom"
    assert {k for k, f in failures.items() if f["status"] == "blocked"} == {
        "segeval/adaptsegnet_n5_s2",
        "slam/harness/walking_xyz/semantic/adaptsegnet_n5_s2",
        "slam/harness/walking_xyz/semantic_geometry/adaptsegnet_n5_s2",
    }
    assert "1 failed, 3 blocked" in text
    assert text.count("| `segeval/adaptsegnet_n5_s2` | blocked |") == 1  # one line per job


def test_write_tables_writes_markdown_json_and_plots(rows: list[dict], tmp_path: Path) -> None:
    data = tbl.write_tables(tmp_path, rows, n_layers=5, header=["# title", ""])
    md = (tmp_path / "tables.md").read_text()
    assert md.startswith("# title\n") and "![ate_per_sequence](plots/ate_per_sequence.png)" in md
    assert json.loads((tmp_path / "tables.json").read_text()) == json.loads(json.dumps(data))
    for name in ("t1_miou.png", "t1_iou_per_class.png", "ate_per_sequence.png"):
        assert (tmp_path / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_runs_csv_round_trip(rows: list[dict], tmp_path: Path) -> None:
    path = tmp_path / "again.csv"
    tbl.write_runs(path, rows)
    header = path.read_text().splitlines()[0].split(",")
    assert tuple(header) == tbl.COLUMNS
    again = tbl.read_runs(path)
    assert [{k: r.get(k) for k in rows[0]} for r in again] == rows


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("kind,id\ntrain,x\n", "missing column(s) status"),
        (
            "kind,id,status\ntrain,x,maybe\n",
            ":2: column status: expected one of ok, failed, blocked, missing, got 'maybe'",
        ),
        (
            "kind,id,status,ate_rmse\nslam,x,ok,fast\n",
            ":2: column ate_rmse: expected a number, got 'fast'",
        ),
    ],
)
def test_read_runs_errors_name_file_and_line(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "runs.csv"
    path.write_text(text)
    with pytest.raises(DataFormatError) as info:
        tbl.read_runs(path)
    assert str(info.value).startswith(str(path)) and message in str(info.value)


def test_improvement_and_ratio_edge_cases() -> None:
    assert tbl.improvement(tbl.Stat((0.0,)), tbl.Stat((0.1,)), "ate_rmse") is None
    assert tbl.improvement(tbl.Stat(()), tbl.Stat((0.1,)), "mIoU") is None
    assert tbl.improvement(tbl.Stat((0.2,)), tbl.Stat((0.1,)), "ate_rmse") == pytest.approx(50.0)
    assert tbl.improvement(tbl.Stat((0.2,)), tbl.Stat((0.1,)), "mIoU") == pytest.approx(-50.0)
    assert tbl.downstream_ratio(0.1, 0.05, 0.12) is None  # oracle no better than no filter
    assert tbl.downstream_ratio(0.1, None, 0.02) is None
    assert tbl.downstream_ratio(0.1, 0.12, 0.02) == pytest.approx(-0.25)  # worse than no filter


def _runs_with_methods_and_crf() -> list[dict]:
    """Source-only, AdaptSegNet (n = 4, 5), MinEnt over seeds 0-1 on one sequence; the adapted
    model of n = 5 also with the dense CRF (segmentation and SLAM)."""
    rows: list[dict] = []
    miou = {
        "source_only": (0.20, 0.22),
        "adaptsegnet_n4": (0.25, 0.27),
        "adaptsegnet_n5": (0.30, 0.34),
        "minent": (0.24, 0.26),
    }
    person = {"source_only": (0.10, 0.14), "adaptsegnet_n5": (0.30, 0.34)}
    for config, values in miou.items():
        method, _, n = config.partition("_n")
        common = {"method": method, "n_layers": int(n) if n else None, "config": config}
        for seed, value in enumerate(values):
            model = f"{config}_s{seed}"
            rows.append(
                {"kind": "train", "id": f"train/{model}", "status": "ok", **common, "seed": seed}
            )
            iou = person.get(config, (0.2, 0.2))[seed]
            for crf in (False, True) if config == "adaptsegnet_n5" else (False,):
                rows.append(
                    {
                        "kind": "segeval",
                        "id": f"segeval/{'crf/' if crf else ''}{model}",
                        "status": "ok",
                        **common,
                        "seed": seed,
                        "sequence": "all",
                        "mIoU": value + (0.04 if crf else 0.0),
                        "IoU_person": iou,
                        "crf": int(crf),
                    }
                )
            variants = ("semantic", "semantic_crf") if config == "adaptsegnet_n5" else ("semantic",)
            for variant in variants:
                crf = variant.endswith("_crf")
                rows.append(
                    {
                        "kind": "slam",
                        "id": f"slam/harness/walking_xyz/{variant}/{model}",
                        "status": "ok",
                        **common,
                        "seed": seed,
                        "system": "harness",
                        "sequence": "walking_xyz",
                        "variant": variant,
                        "ate_rmse": 0.05 - 0.01 * seed - (0.005 if crf else 0.0),
                        "segmentation_ms": 10.0 + (40.0 + 4 * seed if crf else 0.0),
                        "crf_ms": 40.0 + 4 * seed if crf else None,
                        "total_ms": 30.0 + (40.0 if crf else 0.0),
                        "fps": 1000.0 / (30.0 + (40.0 if crf else 0.0)),
                        "crf": int(crf),
                    }
                )
    return rows


def test_methods_crf_and_timing_tables(tmp_path: Path) -> None:
    path = tmp_path / "runs.csv"
    tbl.write_runs(path, _runs_with_methods_and_crf())
    rows = tbl.read_runs(path)
    data, text = tbl.compute(rows, n_layers=5)
    assert data["layout"]["methods"] == ["source_only", "adaptsegnet_n5", "minent"]
    assert data["layout"]["crf_configs"] == ["adaptsegnet_n5"]

    # T1a: the CRF's metrics are not the model's own; Δ in points against source-only
    t1 = {r["config"]: r for r in data["T1"]["segmentation"]}
    assert t1["adaptsegnet_n5"]["mIoU"]["values"] == [0.30, 0.34]
    assert t1["adaptsegnet_n4"]["mIoU_vs_source_only_points"] == pytest.approx(5.0)
    assert "| adaptsegnet_n4 | n/a | 0.260 ± 0.014 (n=2) | +5.00 |" in text

    by_method = {r["config"]: r for r in data["T2"]["by_method"]}
    assert list(by_method) == ["source_only", "adaptsegnet_n5", "minent"]
    assert by_method["adaptsegnet_n5"]["mIoU_vs_source_only_points"] == pytest.approx(11.0)
    assert by_method["adaptsegnet_n5"]["IoU_person_vs_source_only_points"] == pytest.approx(20.0)
    assert by_method["minent"]["mIoU_vs_source_only_points"] == pytest.approx(4.0)
    assert (
        "| adaptsegnet_n5 | 0.320 ± 0.028 (n=2) | +11.00 | 0.320 ± 0.028 (n=2) | +20.00 "
        "| 0.0450 ± 0.0071 (n=2) |"
    ) in text

    crf = [(r["config"], r["filter"], r["crf"], r["mIoU"]["mean"]) for r in data["crf"]]
    assert crf == [
        ("adaptsegnet_n5", "semantic", False, pytest.approx(0.32)),
        ("adaptsegnet_n5", "semantic", True, pytest.approx(0.36)),
    ]
    assert data["crf"][1]["ate_rmse"]["walking_xyz"]["mean"] == pytest.approx(0.04)
    assert "| adaptsegnet_n5 | semantic | on | 0.360 ± 0.028 (n=2) |" in text

    timing = {r["variant"]: r for r in data["timing"]}
    assert timing["semantic_crf"]["crf_ms"]["mean"] == pytest.approx(42.0)
    assert timing["semantic"]["crf_ms"]["n"] == 0  # no CRF in these runs
    assert "| semantic (CRF) | 52.0 ± 2.8 (n=2) | 42.0 ± 2.8 (n=2) | 70.0 ± 0.0 (n=2) |" in text
    assert "| semantic | 10.0 ± 0.0 (n=8) | — | 30.0 ± 0.0 (n=8) |" in text


def test_tables_without_crf_or_timing_columns_leave_them_out(rows: list[dict]) -> None:
    data, text = tbl.compute(rows, n_layers=5)
    assert data["crf"] == [] and data["timing"] == []
    assert "Dense CRF" not in text and "Time per frame" not in text
    assert [r["config"] for r in data["T2"]["by_method"]] == ["source_only", "adaptsegnet_n5"]


def test_mde_is_the_paired_t_tests_smallest_detectable_effect() -> None:
    # n = 8, s = 6: (t_0.975,7 + t_0.80,7) · 6 / √8 = (2.365 + 0.896) · 6 / 2.828 = 6.92
    assert tbl.mde(6.0, 8) == pytest.approx((2.3646 + 0.8960) * 6 / math.sqrt(8), abs=1e-3)
    assert tbl.mde(6.0, 8) == pytest.approx(6.917, abs=1e-3)
    # n = 3, s = 0.1: (4.303 + 1.061) · 0.1 / √3 = 0.310
    assert tbl.mde(0.1, 3) == pytest.approx((4.3027 + 1.0607) * 0.1 / math.sqrt(3), abs=1e-4)
    assert tbl.mde(0.0, 5) == 0.0  # identical differences: any effect shows
    assert tbl.mde(0.3, 1) is None and tbl.mde(None, 4) is None and tbl.mde(0.3, 0) is None
    assert tbl.mde_text(None) == "MDE —" and tbl.mde_text(0.12345) == "MDE 0.12"
    # paired_interval carries it; paired_text prints it on request only
    paired = tbl.paired_interval([0.2, 0.3, 0.1])
    assert paired["mde"] == pytest.approx((4.3027 + 1.0607) * 0.1 / math.sqrt(3), abs=1e-4)
    assert tbl.paired_text(paired).endswith("[-0.05, +0.45]")
    assert tbl.paired_text(paired, with_mde=True).endswith("[-0.05, +0.45], MDE 0.31")
    one = tbl.paired_interval([0.2])
    assert one["mde"] is None and tbl.paired_text(one, with_mde=True) == "+0.20 (1/1 > 0), MDE —"


def _with_target_labels(text: str, config: str, uses: str) -> str:
    """RUNS_CSV with a ``target_labels`` column: ``uses`` on every row of ``config``."""
    lines = text.splitlines()
    header = lines[0].split(",")
    at = header.index("config")
    out = [",".join([*header, "target_labels"])]
    for line in lines[1:]:
        cells = line.split(",")
        out.append(",".join([*cells, uses if cells[at] == config else ""]))
    return "\n".join(out) + "\n"


def _daggered(text: str) -> set[str]:
    """The names marked † in markdown tables and titles."""
    import re

    return set(re.findall(r"([A-Za-z0-9_]+) †", text)) - {"ATL"}  # T2's "with ATL †"


def test_a_runs_csv_without_the_column_marks_nothing_but_the_policy(rows: list[dict]) -> None:
    # an older runs.csv: no target_labels column, no oracle, last checkpoints: no †
    assert "target_labels" not in rows[0]
    data, text = tbl.compute(rows, n_layers=5)
    assert _daggered(text) == set() and tbl.DAGGER_NOTE not in text
    assert data["layout"]["target_labels"] == {}
    assert "\ntarget labels used: none\n" in text  # T0's header line
    assert [r["target_labels"] for r in data["T0"]["rows"]] == ["none", "none"]
    # ... unless the settings say otherwise: a checkpoint policy that reads target labels
    data, text = tbl.compute(rows, n_layers=5, policy="best_target_val")
    assert _daggered(text) == {"source_only", "adaptsegnet_n5"}
    assert "target labels used: none" not in text
    assert (
        "target labels used: source_only (checkpoint selection); adaptsegnet_n5 (checkpoint "
        "selection)"
    ) in text


def test_rows_chosen_with_target_labels_are_marked_in_every_table(tmp_path: Path) -> None:
    path = tmp_path / "runs.csv"
    path.write_text(_with_target_labels(RUNS_CSV, "adaptsegnet_n5", "settings"))
    rows = tbl.read_runs(path)
    data, text = tbl.compute(rows, n_layers=5)
    other, other_text = tbl.compute(tbl.read_runs(_plain(tmp_path)), n_layers=5)
    assert data["layout"]["target_labels"] == {"adaptsegnet_n5": ["settings"]}
    # † on adaptsegnet_n5 wherever it is a row or a side, never on source-only
    assert _daggered(text) == {"adaptsegnet_n5"}
    assert "| adaptsegnet_n5 † | settings | " in text  # T0
    assert "\ntarget labels used: adaptsegnet_n5 (settings)\n" in text  # T0's header line
    assert "| adaptsegnet_n5 † | 0.420 ± 0.028 (n=2, 1 failed) | 0.320 ± 0.028" in text  # T1a
    assert "| adaptsegnet_n5 † | 0.0435 ± 0.0049 (n=2, 1 failed) |" in text  # T1b
    assert "| metric | without ATL | with ATL † | improvement |" in text  # T2
    assert "### T3: without / with multi-view geometry (adaptsegnet_n5 †, harness)" in text
    assert "| adaptsegnet_n5 † | − source_only | +0.25 / +0.29 (2/2 > 0)" in text  # ratio
    assert "| adaptsegnet_n5 † | mean ± s.d. | 0.706 ± 0.062 (n=2) |" in text
    assert "| source_only | mean ± s.d. | 0.375 ± 0.125 (n=3) |" in text
    assert "| adaptsegnet_n5 † | − source_only | +10.00 / +12.00 (2/2 > 0)" in text  # T0
    # the footnote under each table with a †: T0 (4 tables), T1a, T1b, T2, T3, T2 by method,
    # the downstream ratio (semantic, semantic+geometry)
    assert text.count(tbl.DAGGER_NOTE) == 11

    # the other columns are those of the same runs.csv without the column
    def unmarked(md: str) -> str:
        md = md.replace(tbl.DAGGER_NOTE + "\n\n", "").replace(" †", "")
        md = md.replace("target labels used: adaptsegnet_n5 (settings)", "target labels used: none")
        return md.replace("| adaptsegnet_n5 | settings |", "| adaptsegnet_n5 | none |")

    assert unmarked(text) == unmarked(other_text)
    assert (
        data["T1"] == other["T1"]
        and data["downstream_ratio_paired"] == other["downstream_ratio_paired"]
    )


def _plain(tmp_path: Path) -> Path:
    path = tmp_path / "plain.csv"
    path.write_text(RUNS_CSV)
    return path


def test_t0_prints_the_mde_of_each_closure(tmp_path: Path) -> None:
    # source-only, the method and the oracle over three seeds on one sequence; the method's
    # closure per seed 0.2, 0.3, 0.1 (mean 0.2, s = 0.1)
    rows = []
    miou = {"source_only": (0.20, 0.20, 0.20), "adabn": (0.23, 0.23, 0.23),
            "adaptsegnet_n5": (0.24, 0.26, 0.22), "oracle": (0.40, 0.40, 0.40)}  # fmt: skip
    for config, values in miou.items():
        method = config.removesuffix("_n5")
        for seed, value in enumerate(values):
            common = {"status": "ok", "method": method, "config": config, "seed": seed,
                      "n_layers": 5 if config.endswith("_n5") else None}  # fmt: skip
            rows.append({"kind": "train", "id": f"train/{config}_s{seed}", **common})
            rows.append({"kind": "segeval", "id": f"segeval/{config}_s{seed}", **common,
                         "sequence": "walking_xyz", "mIoU": value, "IoU_person": value})  # fmt: skip
    path = tmp_path / "runs.csv"
    tbl.write_runs(path, rows)
    data, text = tbl.compute(tbl.read_runs(path), n_layers=5)
    t0 = {r["config"]: r for r in data["T0"]["rows"]}
    assert t0["adaptsegnet_n5"]["closure_mIoU"]["values"] == pytest.approx([0.2, 0.3, 0.1])
    expected = (4.3027 + 1.0607) * 0.1 / math.sqrt(3)  # 0.310
    assert t0["adaptsegnet_n5"]["closure_mIoU_mde"] == pytest.approx(expected, abs=1e-4)
    assert t0["source_only"]["closure_mIoU_mde"] == 0.0  # closure 0 on every seed
    assert "| MDE closure (mIoU) | MDE closure (person IoU) |" in text
    assert f"(n=3) | {expected:.3f} | {expected:.3f} |" in text
    assert tbl.MDE_FORMULA in text
    # the oracle is marked: it trained on target labels (a reference)
    assert "| oracle † | training |" in text and "target labels used: oracle (training)" in text
    # each row against source-only and AdaBN in points, paired by seed, with the MDE:
    # adaptsegnet − source-only = 4, 6, 2 (mean 4, s = 2): interval 4 ± 4.303 · 2 / √3
    diffs = {(r["config"], r["against"]): r for r in data["T0"]["differences"]}
    assert list(diffs) == [("adabn", "source_only"), ("adaptsegnet_n5", "source_only"),
                           ("adaptsegnet_n5", "adabn"), ("oracle", "source_only"),
                           ("oracle", "adabn")]  # fmt: skip
    paired = diffs[("adaptsegnet_n5", "source_only")]["mIoU"]
    assert paired["values"] == pytest.approx([4.0, 6.0, 2.0])
    half = 4.3027 * 2 / math.sqrt(3)
    assert paired["interval"] == pytest.approx([4 - half, 4 + half], abs=1e-3)
    assert paired["mde"] == pytest.approx((4.3027 + 1.0607) * 2 / math.sqrt(3), abs=1e-3)  # 6.19
    assert (
        f"| adaptsegnet_n5 | − source_only | +4.00 / +6.00 / +2.00 (3/3 > 0), mean +4.00 "
        f"[{4 - half:+.2f}, {4 + half:+.2f}], MDE 6.19 |"
    ) in text
    assert "| adaptsegnet_n5 | − adabn | +1.00 / +3.00 / -1.00 (2/3 > 0)" in text
    assert "| oracle † | − adabn |" in text
    # a single seed: no MDE
    one, one_text = tbl.compute([r for r in tbl.read_runs(path) if r["seed"] == 0], 5)
    assert {r["closure_mIoU_mde"] for r in one["T0"]["rows"]} == {None}
    assert "(n=1) | — | — |" in one_text
    assert "| adaptsegnet_n5 | − source_only | +4.00 (1/1 > 0), MDE — |" in one_text


def test_the_grid_passes_what_target_labels_chose_into_the_job_rows() -> None:
    from uss_slam.pipelines.experiments.grid import (
        PRESET_METHOD_OVERRIDES,
        AdaBNCell,
        TrainCell,
        target_label_uses,
    )

    tuned = PRESET_METHOD_OVERRIDES["tum_like"]["adaptsegnet"]
    cfg = {"data": {"kind": "synthetic", "synthetic": {"shift": "tum_like"}}, "train": {}}
    adapted = TrainCell("adaptsegnet", 0, 5, settings=tuned)
    assert target_label_uses(cfg, adapted) == ("settings",)
    assert target_label_uses(cfg, TrainCell("source_only", 0)) == ()
    assert target_label_uses(cfg, TrainCell("oracle", 0)) == ("training",)
    # settings of the user's own (or {}), real data, and the full preset (not swept): none
    own = TrainCell("adaptsegnet", 0, 5, settings=("model.domain_batch_norm=joint",))
    assert target_label_uses(cfg, own) == ()
    real = {**cfg, "data": {"kind": "real", "synthetic": {"shift": "tum_like"}}}
    assert target_label_uses(real, adapted) == ()
    full = {**cfg, "data": {"kind": "synthetic", "synthetic": {"shift": "full"}}}
    assert target_label_uses(full, adapted) == ()
    best = {**cfg, "train": {"checkpoint": "best_target_val"}}
    assert target_label_uses(best, adapted) == ("settings", "checkpoint selection")
    assert target_label_uses(best, TrainCell("oracle", 0)) == ("training", "checkpoint selection")
    # the rows: a training's, and an AdaBN export of it inherits what chose its checkpoint
    cell = TrainCell("adaptsegnet", 0, 5, settings=tuned, target_labels=("settings",))
    assert cell.describe()["target_labels"] == "settings"
    assert AdaBNCell(cell).describe()["target_labels"] == "settings"
    assert TrainCell("source_only", 0).describe()["target_labels"] is None
    # written and read back through runs.csv
    both = TrainCell("oracle", 1, target_labels=("training", "checkpoint selection"))
    assert both.describe()["target_labels"] == "training;checkpoint selection"


def test_target_labels_init_and_batchnorm_columns_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "runs.csv"
    row = {"kind": "train", "id": "train/oracle_s0", "status": "ok", "method": "oracle",
           "config": "oracle", "seed": 0, "target_labels": "training;checkpoint selection"}  # fmt: skip
    tbl.write_runs(path, [row, {**row, "id": "train/oracle_i1_s0", "init": 1,
                                "batchnorm": "reference", "target_labels": None}])  # fmt: skip
    first, second = tbl.read_runs(path)
    assert first["target_labels"] == "training;checkpoint selection" and first["init"] is None
    assert second["target_labels"] is None
    assert (second["init"], second["batchnorm"]) == (1, "reference")  # the init's seed: an int
    path.write_text("kind,id,status,target_labels\ntrain,x,ok,labels\n")
    with pytest.raises(DataFormatError) as info:
        tbl.read_runs(path)
    assert str(info.value).startswith(str(path)) and (
        ":2: column target_labels: expected training; settings; checkpoint selection separated "
        "by ';', got 'labels'"
    ) in str(info.value)


def test_the_expanded_grid_carries_the_mark_to_every_row_of_a_model() -> None:
    from uss_slam.pipelines.experiments.grid import PRESET_METHOD_OVERRIDES, expand

    tuned = PRESET_METHOD_OVERRIDES["tum_like"]["adaptsegnet"]
    cfg = {
        "data": {"kind": "synthetic", "synthetic": {"shift": "tum_like"}},
        "train": {"checkpoint": "last"},
        "grid": {"methods": ["source_only", "adaptsegnet"], "n_layers": [5], "seeds": [0, 1],
                 "oracle": True, "adabn": True, "adabn_methods": ["source_only", "adaptsegnet"],
                 "method_overrides": {"adaptsegnet": list(tuned)}},
        "sequences": ["walking_xyz"], "variants": ["semantic"], "systems": ["harness"],
        "tables": {"n_layers": 5},
    }  # fmt: skip
    grid = expand(cfg, ["walking_xyz"])
    marks = {m.config: m.describe()["target_labels"] for m in grid.models}
    assert marks == {"source_only": None, "adaptsegnet_n5": "settings", "oracle": "training",
                     "adabn": None, "adaptsegnet_n5_adabn": "settings"}  # fmt: skip
    # the mark is no part of what a training runs: its overrides are those of an unmarked cell
    cell = next(t for t in grid.trainings if t.method == "adaptsegnet")
    assert "settings" not in " ".join(cell.overrides())
    # what the tables make of the rows
    rows = [{"kind": "train", "id": m.id, "status": "ok", **m.describe()} for m in grid.models]
    layout = tbl.layout_from_rows(rows, 5)
    assert dict(layout.target_labels) == {"source_only": (), "adaptsegnet_n5": ("settings",),
                                          "oracle": ("training",), "adabn": (),
                                          "adaptsegnet_n5_adabn": ("settings",)}  # fmt: skip
    assert [layout.name(c) for c in ("source_only", "adaptsegnet_n5")] == [
        "source_only",
        "adaptsegnet_n5 †",
    ]
