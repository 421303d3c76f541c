"""The one plotting module: formats by extension, refused extensions, top-view axes, no leftovers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.slam_eval.scoring import plots

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _helix(n: int = 60) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n)
    return np.stack([np.cos(t), 0.01 * t, 2 * np.sin(t)], axis=1)  # spreads along x and z


def test_top_view_takes_the_two_widest_axes_in_order() -> None:
    assert plots.top_view_axes(_helix()) == (0, 2)
    assert plots.top_view_axes(np.array([[0, 0, 0], [0, 5, 1], [0, 9, 2.0]])) == (1, 2)


def test_formats_follow_the_extension(tmp_path: Path) -> None:
    gt = _helix()
    est = gt + 0.01
    for name, magic in (("t.png", PNG_MAGIC), ("t.PDF", b"%PDF"), ("t.svg", b"<?xml")):
        out = plots.plot_trajectories(tmp_path / name, gt, [("a", est), ("b", est * 1.1)], "x")
        assert out == tmp_path / name and out.read_bytes().startswith(magic)
    errors = np.linspace(0, 0.02, 60)
    plots.plot_error_over_time(tmp_path / "e.png", np.arange(60) / 30.0, errors, "ATE")
    assert (tmp_path / "e.png").read_bytes().startswith(PNG_MAGIC)
    # Only the finished files: no temporary file is left beside them.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.png", "t.PDF", "t.png", "t.svg"]


@pytest.mark.parametrize("name", ["plot.xyz", "plot", "plot.png.bak"])
def test_unknown_extension_is_one_line_naming_path_and_formats(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    with pytest.raises(UssSlamError) as info:
        plots.plot_trajectories(path, _helix(), [], "x")
    message = str(info.value)
    assert len(message.splitlines()) == 1
    assert message.startswith(f"{path}: ") and ".png" in message and ".pdf" in message
    assert not path.exists() and list(tmp_path.iterdir()) == []


def test_check_plot_path_accepts_matplotlib_formats(tmp_path: Path) -> None:
    assert {"png", "pdf", "svg"} <= set(plots.plot_formats())
    assert plots.check_plot_path(tmp_path / "a.Svg") == tmp_path / "a.Svg"


def test_unwritable_folder_is_a_user_error(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("a file\n")
    target = tmp_path / "afile" / "t.png"
    with pytest.raises(UssSlamError, match=r"afile/t\.png: cannot write the plot"):
        plots.plot_error_over_time(target, np.arange(3.0), np.zeros(3), "x")


def test_a_new_folder_on_the_way_is_created(tmp_path: Path) -> None:
    """As for every output file (``uss-vocab build --out a/b/v.txt``, the path layer's rule)."""
    target = tmp_path / "new" / "plots" / "t.png"
    assert plots.plot_error_over_time(target, np.arange(3.0), np.zeros(3), "x") == target
    assert target.is_file()
