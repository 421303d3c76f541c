"""What the demo's table says (``demo_report.findings``): computed from the rows, exact."""

from __future__ import annotations

from typing import Any

from uss_slam.pipelines import demo_report


def _row(variant: str, label: str, filters: list[str], ate: float | None, lo: float | None,
         hi: float | None, dropped: dict[str, int] | None = None) -> dict[str, Any]:  # fmt: skip
    return {
        "variant": variant,
        "label": label,
        "filters": filters,
        "ate_rmse": ate,
        "ate_min": lo,
        "ate_max": hi,
        "repeats": 3,
        "keypoints": {"extracted": 10000, "kept": 9000, "dropped": dropped or {}},
    }


def _rows(adapted: float, geometry: float, geo_dropped: int) -> list[dict[str, Any]]:
    sem = ["semantic"]
    return [
        _row("none", "no filter", [], 0.1, 0.09, 0.12),
        _row("labels", "ground-truth masks", sem, 0.01, 0.01, 0.011, {"semantic": 800}),
        _row("source_only", "source-only", sem, 0.12, 0.11, 0.13, {"semantic": 300}),
        _row("adabn", "AdaBN", sem, 0.08, 0.07, 0.09, {"semantic": 500}),
        _row(
            "adapted", "adapted", sem, adapted, adapted - 0.001, adapted + 0.001, {"semantic": 400}
        ),  # fmt: skip
        _row(
            "adapted_geometry",
            "adapted + geometry",
            ["semantic", "geometry"],
            geometry,
            geometry - 0.001,
            geometry + 0.001,
            {"semantic": 400, "geometry": geo_dropped},
        ),  # fmt: skip
    ]


def test_masks_against_no_filter_and_adapted_against_source_only() -> None:
    first, second, _ = demo_report.findings(_rows(0.05, 0.2, 1000))
    assert first == (
        "On this sequence (one training seed, median of 3 SLAM runs per row), against no filter "
        "(0.1000 m): ground-truth masks 0.0100 m (-90%), source-only 0.1200 m (+20%), AdaBN "
        "0.0800 m (-20%), adapted 0.0500 m (-50%); masks that lower the median ATE: "
        "ground-truth masks, AdaBN and adapted; that do not: source-only."
    )
    assert second == (
        "Adapted is below source-only by 0.0700 m (-58%); their repeats' ranges do not overlap."
    )


def test_overlapping_ranges_do_not_separate() -> None:
    _, second, _ = demo_report.findings(_rows(0.1195, 0.2, 1000))
    assert second == (
        "Adapted is below source-only by 0.0005 m (-0%); their repeats' ranges overlap, so these "
        "runs do not separate them."
    )


def test_geometry_that_hurts_says_what_it_dropped() -> None:
    # 9600 keypoints kept by the masks, 1000 dropped by geometry, 800 on walkers at most
    *_, line = demo_report.findings(_rows(0.05, 0.2, 1000))
    assert line == (
        "Geometry does not help here: 0.2000 m against 0.0500 m with the masks alone (+300%); "
        "it dropped 1000 keypoints, 10.4% of those the masks kept, more than the 800 the "
        "ground-truth masks drop on walkers in the whole sequence: at least 200 were on static "
        "structure."
    )
    *_, fewer = demo_report.findings(_rows(0.05, 0.2, 500))
    assert fewer.endswith("it dropped 500 keypoints, 5.2% of those the masks kept.")


def test_geometry_that_helps() -> None:
    *_, line = demo_report.findings(_rows(0.05, 0.04, 100))
    assert line == (
        "Geometry helps: 0.0400 m against 0.0500 m with the masks alone (-20%); their repeats' "
        "ranges do not overlap; it dropped 100 keypoints, 1.0% of those the masks kept."
    )
    *_, close = demo_report.findings(_rows(0.05, 0.0495, 100))
    assert close.startswith(
        "Geometry lowers the median ATE: 0.0495 m against 0.0500 m with the masks alone (-1%); "
        "their repeats' ranges overlap, so these runs do not separate them; it dropped 100"
    )


def test_same_masks_make_the_ate_difference_noise() -> None:
    rows = _rows(0.1195, 0.2, 1000)
    rows[2]["person_IoU"], rows[4]["person_IoU"] = 0.2381, 0.2384
    _, second, _ = demo_report.findings(rows)
    assert second.endswith(
        "so these runs do not separate them; the adapted masks score as source-only's (person "
        "IoU 0.238 and 0.238), so the ATE difference is SLAM noise, not adaptation."
    )


def test_a_run_without_ate() -> None:
    rows = _rows(0.05, 0.2, 10)
    rows[2]["ate_rmse"] = None
    first, second, _ = demo_report.findings(rows)
    assert "source-only no ATE, AdaBN" in first and first.endswith("that do not: source-only.")
    assert second == "Adapted and source-only cannot be compared: a run has no ATE."


def _trained(at_chance: bool, main: float, aux: float) -> dict[str, float]:
    return {"train/d_at_chance": float(at_chance), "train/d_acc_main_peak": main,
            "train/d_acc_aux_peak": aux, "val/mIoU": 0.3}  # fmt: skip


def test_a_discriminator_at_chance_is_said_under_the_adapted_line() -> None:
    lines = demo_report.findings(_rows(0.05, 0.2, 1000), _trained(True, 0.55, 0.52))
    assert len(lines) == 4 and lines[3].startswith("Geometry ")
    assert lines[2] == (
        "The adapted training's discriminators stayed at chance (largest 25-iteration mean of "
        "the domain accuracy: main 0.55, aux 0.52; 0.5 is chance): the adversarial term did not "
        "act, so the adapted row is source-only in another BatchNorm mode, not adaptation."
    )


def test_discriminators_that_left_chance_are_said_with_their_peaks() -> None:
    line = demo_report.findings(_rows(0.05, 0.2, 1000), _trained(False, 0.87, 0.61))[2]
    assert line == (
        "The adapted training's discriminators told the domains apart (largest 25-iteration "
        "mean of the domain accuracy: main 0.87, aux 0.61; 0.5 is chance)."
    )


def test_no_discriminator_figures_no_line() -> None:
    assert len(demo_report.findings(_rows(0.05, 0.2, 1000), {"val/mIoU": 0.3})) == 3
    assert len(demo_report.findings(_rows(0.05, 0.2, 1000), None)) == 3
