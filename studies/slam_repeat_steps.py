"""Where do repeated harness runs part ways? Per step between consecutive tracked frames of each
repeat trajectory (``<run>/repeats/trajectory_<i>.txt``), the relative pose error against the
ground truth (rotation degrees, translation cm); prints the worst steps per repeat.

    python studies/slam_repeat_steps.py <run folder> <sequence folder> [--top 4]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def load(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = [
        [float(v) for v in line.split()]
        for line in path.read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    a = np.array(rows)
    return a[:, 0], np.stack([pose(r) for r in a[:, 1:]])


def pose(r: np.ndarray) -> np.ndarray:
    x, y, z, w = r[3:7] / np.linalg.norm(r[3:7])
    t = np.eye(4)
    t[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    t[:3, 3] = r[:3]
    return t


def angle(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("run", type=Path)
    p.add_argument("sequence", type=Path)
    p.add_argument("--top", type=int, default=4)
    a = p.parse_args()
    gt_t, gt = load(a.sequence / "groundtruth.txt")
    for traj in sorted((a.run / "repeats").glob("trajectory_*.txt")):
        t, est = load(traj)
        idx = np.abs(gt_t[None, :] - t[:, None]).argmin(axis=1)
        g = gt[idx]
        steps = []
        for i in range(1, len(t)):
            rel_e = np.linalg.inv(est[i - 1]) @ est[i]
            rel_g = np.linalg.inv(g[i - 1]) @ g[i]
            err = np.linalg.inv(rel_g) @ rel_e
            steps.append(
                (
                    angle(err[:3, :3]),
                    100 * np.linalg.norm(err[:3, 3]),
                    i,
                    t[i],
                    angle(rel_g[:3, :3]),
                )
            )
        steps.sort(reverse=True)
        worst = ", ".join(
            f"#{i} {s:.3f}: {r:.2f}° {c:.1f}cm (motion {m:.1f}°)"
            for r, c, i, s, m in steps[: a.top]
        )
        print(f"{traj.name}: {worst}")


if __name__ == "__main__":
    main()
