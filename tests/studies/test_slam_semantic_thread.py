"""``studies/slam_semantic_thread.py``: its cells and its table row."""

from __future__ import annotations

from pathlib import Path

from uss_slam.testing.scripts import load_script

study = load_script(Path(__file__).resolve().parents[2] / "studies" / "slam_semantic_thread.py")


def test_cells_in_order_with_their_overrides() -> None:
    cells = study.cells([2.9, 0.5], baseline=True)
    assert [name for name, _ in cells] == ["per-frame", "thread 2.9 s", "thread 0.5 s", "no filter"]
    assert "segmenter.latency_s=0.5" in cells[2][1] and "segment=thread" in cells[2][1]
    assert cells[0][1] == ["segment=every_frame", "filters=[semantic]"]
    with_key = study.cells([0.5], baseline=True, thread_set=["slam.provisional_points=true"])
    assert [o[-1] == "slam.provisional_points=true" for _, o in with_key] == [False, True, False]


def test_row_gives_the_ratio_and_both_tracked_shares() -> None:
    ref = {"ate_median": 0.004, "ate_min": 0.0039, "ate_max": 0.0041, "tracked_fraction": 0.78,
           "fps": 9.0, "masks": 300, "load": 12.0}  # fmt: skip
    cell = dict(ref, ate_median=0.018, ate_min=0.017, ate_max=0.02, tracked_fraction=0.9, masks=14)
    line = study.row("walking_xyz_s2", "thread 0.5 s", cell, ref)
    assert line == (
        "| walking_xyz_s2 | thread 0.5 s | 0.0180 (0.0170–0.0200) | ×4.50 | 90.0% (per-frame "
        "78.0%) | 9.0 | 14 | 12.0 |"
    )
    single = dict(cell, ate_min=None, ate_max=None)
    assert "| 0.0180 | ×4.50 |" in study.row("s", "c", single, ref)


def test_row_names_the_lowest_repeats_tracked_share() -> None:
    ref = {"ate_median": 0.004, "ate_min": None, "ate_max": None, "tracked_fraction": 1.0,
           "fps": 9.0, "masks": 300, "load": 2.0}  # fmt: skip
    cell = dict(ref, tracked_repeats=[0.107, 1.0, 0.417])
    assert "100.0% (per-frame 100.0%; lowest repeat 10.7%)" in study.row("s", "c", cell, ref)


def test_a_label_names_the_candidates_thread_cells_apart() -> None:
    cells = study.cells([0.5], baseline=False, thread_set=["slam.mask_max_age_s=1.0"], label="age1")
    assert [name for name, _ in cells] == ["per-frame", "thread 0.5 s age1"]
    assert cells[1][1][-1] == "slam.mask_max_age_s=1.0"
