"""Trajectory and error plots: the one place that draws them (``uss-slam`` reports, ``uss-traj
ate --plot``, ``uss-demo``).

- :func:`plot_trajectories`: top view of the ground truth and one or more aligned estimates
  (the two axes along which the ground truth spreads most).
- :func:`plot_error_over_time`: a per-pose error (ATE) over time with its RMSE.
- :func:`plot_ate`: both side by side in one figure, from an :class:`~.metrics.AteResult`.

Figures are drawn on a plain :class:`matplotlib.figure.Figure` (Agg for raster formats; pyplot's
global state and backend are left alone) and saved atomically: to a temporary file beside the
target, then renamed, so a reader never sees half a file. The format follows the file extension;
:func:`check_plot_path` refuses an extension matplotlib cannot write, before any work is done.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import atomic_path
from uss_slam.core.tum_io import StrPath

from .run_folder import TMP_PREFIX

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .metrics import AteResult

AXIS_NAMES = "xyz"
ESTIMATE_COLORS = ("tab:blue", "tab:green", "tab:orange", "tab:purple", "tab:brown", "tab:pink")
"""Colours of successive estimates in :func:`plot_trajectories` (ground truth is black)."""
DPI = 110


def plot_formats() -> tuple[str, ...]:
    """File extensions (without the dot) matplotlib can save to, e.g. ``png``, ``pdf``, ``svg``."""
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(FigureCanvasBase.get_supported_filetypes()))


def check_plot_path(path: StrPath, key: str | None = None) -> Path:
    """``path`` as a :class:`~pathlib.Path` if its extension is a plot format, else a
    :class:`UssSlamError` naming the path (``key=<path>`` with ``key``, e.g. ``--plot``) and
    the accepted extensions."""
    path = Path(path)
    formats = plot_formats()
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in formats:
        got = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise UssSlamError(
            f"{f'{key}=' if key else ''}{path}: {got} is not a plot format; expected one of "
            + ", ".join(f".{f}" for f in formats)
        )
    return path


def top_view_axes(positions: np.ndarray) -> tuple[int, int]:
    """The two coordinate axes (ascending) along which ``positions`` (N, 3) spread most."""
    spread = np.ptp(np.asarray(positions, dtype=np.float64).reshape(-1, 3), axis=0)
    first, second = sorted(int(a) for a in np.argsort(-spread, kind="stable")[:2])
    return first, second


def _figure(width: float, height: float, columns: int = 1) -> tuple[Figure, list[Axes]]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    axes = [fig.add_subplot(1, columns, k + 1) for k in range(columns)]
    return fig, axes


def _save(fig: Figure, path: StrPath) -> Path:
    """Save ``fig`` to ``path`` atomically (temporary sibling, then rename); a folder on the way
    that does not exist is created, as for every output file (``core.paths.output_file``)."""
    path = check_plot_path(path)
    fig.tight_layout()
    try:
        with atomic_path(path, prefix=TMP_PREFIX) as tmp:
            fig.savefig(tmp, format=path.suffix.lower().lstrip("."), dpi=DPI)
    except OSError as err:
        raise DataFormatError(path, f"cannot write the plot ({err.strerror})") from None
    return path


def draw_top_view(
    ax: Axes,
    ground_truth: np.ndarray | None,
    estimates: Sequence[tuple[str, np.ndarray]],
    title: str,
    colors: Sequence[str] | None = None,
) -> None:
    """Top view on ``ax``: ``ground_truth`` (N, 3) metres dashed black (None = none), each
    ``(label, positions (M, 3))`` of ``estimates`` in its colour."""
    reference = ground_truth if ground_truth is not None else estimates[0][1]
    a, b = top_view_axes(reference)
    if ground_truth is not None:
        ax.plot(ground_truth[:, a], ground_truth[:, b], "k--", lw=1.2, label="ground truth")
    colors = colors or ESTIMATE_COLORS
    for k, (label, positions) in enumerate(estimates):
        ax.plot(positions[:, a], positions[:, b], "-", color=colors[k % len(colors)], lw=1.1,
                label=label)  # fmt: skip
    ax.set_xlabel(f"{AXIS_NAMES[a]} [m]")
    ax.set_ylabel(f"{AXIS_NAMES[b]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)


def draw_error_over_time(
    ax: Axes, stamps: np.ndarray, errors: np.ndarray, title: str, label: str = "ATE"
) -> None:
    """``errors`` (N,) metres over ``stamps`` (N,) seconds (from the first), in centimetres, with
    the RMSE as a dotted line."""
    stamps = np.asarray(stamps, dtype=np.float64)
    errors = np.asarray(errors, dtype=np.float64)
    rmse = float(np.sqrt(np.mean(errors**2))) if len(errors) else float("nan")
    t = stamps - stamps[0] if len(stamps) else stamps
    ax.plot(t, errors * 100.0, lw=1.0, color="tab:red")
    ax.axhline(rmse * 100.0, color="k", ls=":", lw=1, label=f"RMSE {rmse:.4f} m")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{label} [cm]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)


def plot_trajectories(
    path: StrPath,
    ground_truth: np.ndarray | None,
    estimates: Sequence[tuple[str, np.ndarray]],
    title: str,
    colors: Sequence[str] | None = None,
) -> Path:
    """Save the top view of :func:`draw_top_view` to ``path`` (format from its extension)."""
    if ground_truth is None and not estimates:
        raise ValueError("plot_trajectories needs a ground truth or at least one estimate")
    fig, (ax,) = _figure(6.5, 5.5)
    draw_top_view(ax, ground_truth, estimates, title, colors)
    return _save(fig, path)


def plot_error_over_time(
    path: StrPath, stamps: np.ndarray, errors: np.ndarray, title: str, label: str = "ATE"
) -> Path:
    """Save the error-over-time plot of :func:`draw_error_over_time` to ``path``."""
    fig, (ax,) = _figure(7.0, 3.2)
    draw_error_over_time(ax, stamps, errors, title, label)
    return _save(fig, path)


def plot_ate(path: StrPath, result: AteResult, title: str = "") -> Path:
    """Save the aligned top view and the ATE over time of ``result`` side by side to ``path``."""
    prefix = f"{title}: " if title else ""
    fig, (top, err) = _figure(11.0, 4.5, columns=2)
    draw_top_view(
        top,
        result.gt_positions,
        [(f"estimate ({result.align})", result.est_positions)],
        f"{prefix}trajectory, top view ({result.stats.pairs} poses)",
    )
    draw_error_over_time(err, result.stamps, result.errors, f"{prefix}ATE over time")
    return _save(fig, path)
