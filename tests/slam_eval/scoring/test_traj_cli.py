"""``uss-traj``: JSON and table output, agreement with evo on files, exit codes, bad inputs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from evo_helpers import evo_ape

from uss_slam.core.tum_io import Trajectory, write_trajectory
from uss_slam.slam_eval.scoring.traj_cli import main

if sys.version_info >= (3, 11):
    from evo import main_rpe
    from evo.core import sync
    from evo.core.metrics import PoseRelation, Unit
    from evo.tools import file_interface

    HAVE_EVO = True
else:  # pragma: no cover
    HAVE_EVO = False

needs_evo = pytest.mark.skipif(not HAVE_EVO, reason="evo needs Python >= 3.11")

STAT_KEYS = ["rmse", "mean", "median", "std", "min", "max", "pairs"]
GOOD = "1.000000 0.1 0.2 0.3 0.0 0.0 0.0 1.0\n"


def write_pair(folder: Path, seed: int = 0) -> tuple[Path, Path]:
    """A ~100 Hz ground truth and a noisy, rigidly moved ~30 Hz estimate, jittered stamps."""
    rng = np.random.default_rng(seed)
    n = 300
    stamps = 1_305_031_102.0 + np.cumsum(rng.uniform(0.008, 0.012, n))
    positions = np.cumsum(rng.normal(0.0, 0.01, (n, 3)), axis=0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    gt = Trajectory(stamps, positions, q)
    idx = np.arange(0, n, 3)
    poses = gt.matrices()[idx]
    poses[:, :3, 3] += rng.normal(0.0, 0.02, (len(idx), 3))
    poses[:, :3, 3] += [1.0, -2.0, 0.5]
    est = Trajectory.from_matrices(stamps[idx] + rng.uniform(-0.003, 0.003, len(idx)), poses)
    gt_path, est_path = folder / "groundtruth.txt", folder / "trajectory.txt"
    write_trajectory(gt_path, gt)
    write_trajectory(est_path, est)
    return gt_path, est_path


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def evo_files(gt: Path, est: Path, max_diff: float, offset: float = 0.0):
    return sync.associate_trajectories(
        file_interface.read_tum_trajectory_file(str(gt)),
        file_interface.read_tum_trajectory_file(str(est)),
        max_diff=max_diff,
        offset_2=offset,
    )


# --------------------------------------------------------------------------- output


@needs_evo
@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
def test_ate_json_agrees_with_evo_ape(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], align: str
) -> None:
    gt, est = write_pair(tmp_path)
    code, out, err = run(capsys, "ate", gt, est, "--align", align, "--offset", "0.001", "--json")
    assert code == 0 and err == ""
    assert len(out.strip().splitlines()) == 1
    result = json.loads(out)
    assert list(result) == STAT_KEYS
    ref, sync_est = evo_files(gt, est, 0.02, 0.001)
    expected = evo_ape(ref, sync_est, align)
    assert result["pairs"] == len(expected.np_arrays["error_array"]) == 100
    for key in STAT_KEYS[:-1]:
        assert abs(result[key] - expected.stats[key]) < 1e-9, key


@needs_evo
def test_rpe_json_agrees_with_evo_rpe(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = write_pair(tmp_path, seed=1)
    code, out, _ = run(capsys, "rpe", gt, est, "--delta", "2", "--unit", "frames", "--json")
    assert code == 0
    result = json.loads(out)
    assert list(result) == ["trans", "rot_deg"]
    for key, relation in (
        ("trans", PoseRelation.translation_part),
        ("rot_deg", PoseRelation.rotation_angle_deg),
    ):
        ref, sync_est = evo_files(gt, est, 0.02)
        expected = main_rpe.rpe(
            ref, sync_est, relation, delta=2, delta_unit=Unit.frames, all_pairs=False
        )
        assert list(result[key]) == STAT_KEYS
        assert result[key]["pairs"] == len(expected.np_arrays["error_array"]) == 49
        for stat in STAT_KEYS[:-1]:
            assert abs(result[key][stat] - expected.stats[stat]) < 1e-9, (key, stat)


def test_tables_show_settings_and_statistics(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gt, est = write_pair(tmp_path)
    code, out, _ = run(capsys, "ate", gt, est, "--align", "sim3")
    assert code == 0
    code_json, out_json, _ = run(capsys, "ate", gt, est, "--align", "sim3", "--json")
    stats = json.loads(out_json)
    assert "Sim(3) Umeyama alignment" in out and "100 pose pairs" in out and "scale:" in out
    for key in STAT_KEYS[:-1]:
        assert f"{key:>8}  {stats[key]:.6f} m" in out
    code, out, _ = run(capsys, "rpe", gt, est, "--delta", "0.5", "--unit", "seconds")
    assert code == 0
    assert "RPE for delta = 0.5 seconds" in out and "skipped across gaps" in out
    assert "trans (m)" in out and "rot (deg)" in out
    code, out_json, _ = run(capsys, "rpe", gt, est, "--delta", "0.5", "--unit", "seconds", "--json")
    rpe_stats = json.loads(out_json)
    rmse_line = next(line for line in out.splitlines() if line.strip().startswith("rmse"))
    assert rmse_line.split()[1:] == [
        f"{rpe_stats['trans']['rmse']:.6f}",
        f"{rpe_stats['rot_deg']['rmse']:.6f}",
    ]


def test_plot_writes_a_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = write_pair(tmp_path)
    png = tmp_path / "ate.png"
    code, _, err = run(capsys, "ate", gt, est, "--plot", png)
    assert code == 0 and err == ""
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    code, _, err = run(capsys, "ate", gt, est, "--plot", tmp_path / "new" / "ate.png")
    assert code == 0 and (tmp_path / "new" / "ate.png").is_file()  # folders on the way: made
    (tmp_path / "afile").write_text("a file\n")
    code, _, err = run(capsys, "ate", gt, est, "--plot", tmp_path / "afile" / "ate.png")
    assert code == 1 and len(err.strip().splitlines()) == 1 and "--plot" in err


def test_console_script_exit_codes(tmp_path: Path) -> None:
    """The installed entry point, end to end: 0 on success, 1 on a bad file, 2 on bad arguments."""
    script = Path(sys.executable).with_name("uss-traj")
    assert script.exists(), "run: pip install -e '.[dev]'"
    gt, est = write_pair(tmp_path)
    ok = subprocess.run([script, "ate", gt, est, "--json"], capture_output=True, text=True)
    assert ok.returncode == 0 and json.loads(ok.stdout)["pairs"] == 100
    bad = tmp_path / "bad.txt"
    bad.write_text("# header\n1.0 0 0 0 0 0 0\n")
    fail = subprocess.run([script, "ate", gt, bad], capture_output=True, text=True)
    assert fail.returncode == 1 and fail.stdout == ""
    assert fail.stderr.strip() == (
        f"uss-traj: error: {bad}:2: expected 8 columns 'timestamp tx ty tz qx qy qz qw', got 7"
    )
    usage = subprocess.run([script, "ate", gt], capture_output=True, text=True)
    assert usage.returncode == 2


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("body", "line", "fragment"),
    [
        (GOOD + "2.0 0.1 0.2 0.3 0.0 0.0 1.0\n", 3, "expected 8 columns"),
        (GOOD + "2.0 0.1 0.2 zero 0.0 0.0 0.0 1.0\n", 3, "expected a number for tz, got 'zero'"),
        (GOOD + "2.0 0.1 0.2 0.3 0.0 0.0 0.5 1.0\n", 3, "unit norm"),
        (GOOD + "0.5 0.1 0.2 0.3 0.0 0.0 0.0 1.0\n", 3, "timestamps must increase"),
        (GOOD + "1.0 0.1 0.2 0.3 0.0 0.0 0.0 1.0\n", 3, "duplicate timestamp"),
        (GOOD + "2.0 0.1 0.2 nan 0.0 0.0 0.0 1.0\n", 3, "finite number"),
    ],
    ids=["columns", "non-numeric", "non-unit-quaternion", "unsorted", "duplicate", "nan"],
)
@pytest.mark.parametrize("which", ["gt", "est"])
def test_bad_file_is_one_line_naming_file_and_line(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    body: str,
    line: int,
    fragment: str,
    which: str,
) -> None:
    gt, est = write_pair(tmp_path)
    bad = tmp_path / "bad.txt"
    bad.write_text("# timestamp tx ty tz qx qy qz qw\n" + body)
    args = (bad, est) if which == "gt" else (gt, bad)
    for command in (["ate", *args], ["rpe", *args, "--delta", "1"]):
        code, out, err = run(capsys, *command)
        assert code == 1 and out == ""
        lines = err.strip().splitlines()
        assert len(lines) == 1
        assert lines[0].startswith(f"uss-traj: error: {bad}:{line}: ")
        assert fragment in lines[0]


def test_fewer_than_three_associated_poses(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gt, _ = write_pair(tmp_path)
    est = tmp_path / "far.txt"
    est.write_text(
        "".join(f"{t:.6f} 0 0 0 0 0 0 1\n" for t in (1_305_031_102.5, 1_305_031_102.6, 2e9))
    )
    for command in (["ate", gt, est], ["rpe", gt, est]):
        code, out, err = run(capsys, *command, "--max-diff", "0.001", "--offset", "0")
        assert code == 1 and out == ""
        (line,) = err.strip().splitlines()
        assert str(est) in line and str(gt) in line
        assert "max_diff 0.001 s" in line and "offset 0 s" in line and "at least 3" in line
    # With the default tolerance the two overlapping stamps associate: still fewer than three.
    code, _, err = run(capsys, "ate", gt, est, "--max-diff", "0.02")
    assert code == 1 and "only 2 of its 3 poses" in err


def test_missing_file_directory_and_empty_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gt, est = write_pair(tmp_path)
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing here\n")
    cases = [
        (tmp_path / "nope.txt", "does not exist"),
        (tmp_path, "is a folder; expected a file"),
        (empty, "no poses"),
    ]
    for path, fragment in cases:
        code, out, err = run(capsys, "ate", gt, path)
        assert code == 1 and out == ""
        (line,) = err.strip().splitlines()
        assert line.startswith(f"uss-traj: error: {path}: ") and fragment in line


def test_rpe_delta_too_long_is_a_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gt, est = write_pair(tmp_path)
    code, out, err = run(capsys, "rpe", gt, est, "--delta", "1000")
    assert code == 1 and out == ""
    (line,) = err.strip().splitlines()
    assert "no pose pairs 1000 frames apart" in line and str(est) in line


@pytest.mark.parametrize(
    "argv",
    [
        ["ate", "gt.txt"],
        ["ate", "gt.txt", "est.txt", "--align", "se2"],
        ["ate", "gt.txt", "est.txt", "--max-diff", "-0.1"],
        ["ate", "gt.txt", "est.txt", "--offset", "soon"],
        ["rpe", "gt.txt", "est.txt", "--delta", "1.5"],
        ["rpe", "gt.txt", "est.txt", "--delta", "0", "--unit", "seconds"],
        ["rpe", "gt.txt", "est.txt", "--unit", "metres"],
        ["rpe", "gt.txt", "est.txt", "--delta", "inf", "--unit", "seconds"],
        ["ate", "gt.txt", "est.txt", "--bands", "0"],
        ["rpe", "gt.txt", "est.txt", "--bands", "0.5"],
        ["plot", "gt.txt", "est.txt"],
        [],
    ],
)
def test_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str], argv: list[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "usage: uss-traj" in err and "error:" in err


def test_plot_with_unknown_extension_fails_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gt, est = write_pair(tmp_path)
    target = tmp_path / "ate.jpgg"
    code, out, err = run(capsys, "ate", gt, est, "--plot", target)
    assert code == 1 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"uss-traj: error: --plot={target}: extension '.jpgg'"
    )
    assert ".png" in lines[0] and ".svg" in lines[0]
    assert not target.exists()


def test_ate_bands_split_the_error_into_slow_and_fast_parts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gt, est = write_pair(tmp_path)
    code, out, _ = run(capsys, "ate", gt, est, "--json", "--bands", "0.5")
    assert code == 0
    data = json.loads(out)
    bands = data["bands"]
    assert bands["window_s"] == 0.5 and bands["rmse"] == pytest.approx(data["rmse"])
    # the estimate's error is white noise per pose: almost all of it is fast
    assert bands["fast"] > 3 * bands["slow"] > 0
    code, out, _ = run(capsys, "ate", gt, est, "--bands", "0.5")
    assert code == 0
    assert f"slow  {bands['slow']:.6f} m  (RMSE of the error averaged over 0.5 s)" in out
    assert f"fast  {bands['fast']:.6f} m  (RMSE of the rest)" in out
    assert "bands" not in json.loads(run(capsys, "ate", gt, est, "--json")[1])
