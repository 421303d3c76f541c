"""benchmarks/module_ab.py: two copies of a hot module compared output by output, then timed."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from uss_slam.core.tum_io import TUM_CAMERAS
from uss_slam.slam_eval.frontend import orb
from uss_slam.slam_eval.matching import descriptor
from uss_slam.testing.scripts import load_script

module_ab = load_script(Path(__file__).resolve().parents[2] / "benchmarks" / "module_ab.py")


def _grays(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    out = []
    for _ in range(n):
        image = cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (5, 5), 1.5)
        for _ in range(40):  # squares of many sizes: corners on every level
            x, y, s = int(rng.integers(0, 150)), int(rng.integers(0, 110)), int(rng.integers(3, 30))
            cv2.rectangle(image, (x, y), (x + s, y + s), int(rng.integers(0, 256)), -1)
        out.append(image)
    return out


def _copy(tmp_path: Path, module, name: str, old: str = "", new: str = "") -> Path:
    text = Path(module.__file__).read_text()
    assert not old or old in text
    path = tmp_path / f"{name}.py"
    path.write_text(text.replace(old, new) if old else text)
    return path


def test_orb_copies_compared_then_timed_in_turns(tmp_path) -> None:
    before = module_ab.load_copy(_copy(tmp_path, orb, "orb_a"), "orb_a")
    after = module_ab.load_copy(_copy(tmp_path, orb, "orb_b"), "orb_b")
    camera = TUM_CAMERAS["fr3"].scaled(160, 120)
    old, new = module_ab.compare_orb(before, after, _grays(2), camera, rounds=3)
    assert len(old) == len(new) == 3 and min(old + new) > 0
    # A copy whose descriptors differ is stopped at the first frame, naming the field.
    changed = _copy(
        tmp_path, orb, "orb_c", "return self.describe(xy, octave, angle, response, descriptors,",
        "return self.describe(xy, octave, angle, response, descriptors ^ 1,",
    )  # fmt: skip
    with pytest.raises(SystemExit, match="frame 0 .*descriptors differs"):
        module_ab.compare_orb(before, module_ab.load_copy(changed, "orb_c"), _grays(1), camera, 1)


def test_matching_copies_compared_then_timed_in_turns(tmp_path) -> None:
    rng = np.random.default_rng(1)
    kp_uv = rng.uniform(0, 640, (300, 2))
    kp_desc = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    desc = kp_desc[:100].copy()
    desc[:, 0] ^= 0x01  # 1 bit from their keypoints: every point matches
    proj = kp_uv[:100] + 1.0
    args = (proj, np.full(100, 8.0), np.zeros(100, int), (desc,), kp_uv, np.zeros(300, int),
            kp_desc, np.ones(300, bool), (640, 480))  # fmt: skip
    before = module_ab.load_copy(_copy(tmp_path, descriptor, "desc_a"), "desc_a")
    after = module_ab.load_copy(_copy(tmp_path, descriptor, "desc_b"), "desc_b")
    assert len(before.guided_match(*args)) == 100
    old, new = module_ab.compare_matching(before, after, [(args, {})] * 2, frames=2, rounds=2)
    assert len(old) == len(new) == 2
    changed = _copy(tmp_path, descriptor, "desc_c", "ratio: float = 0.8", "ratio: float = 0.0")
    with pytest.raises(SystemExit, match="call 0: query differs"):
        module_ab.compare_matching(
            before, module_ab.load_copy(changed, "desc_c"), [(args, {})], 1, 1
        )


def test_whole_runs_in_turns_compare_trajectories(tmp_path, synthetic_sequence, capsys) -> None:
    path = synthetic_sequence(preset="walking_xyz", frames=30)
    before = module_ab.load_copy(_copy(tmp_path, descriptor, "desc_w"), "desc_w")
    module_ab.whole_runs(before, descriptor, path, pairs=1)
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(": ")[1].split(" CPU")[0] for line in lines] == [
        "main thread", "main process", "worker process"
    ]  # fmt: skip
    # Guided matching with a stricter distance bound changes the trajectory: stopped, named.
    changed = _copy(
        tmp_path, descriptor, "desc_x", "(dist[best] <= max_distance)",
        "(dist[best] <= max_distance // 3)",
    )  # fmt: skip
    with pytest.raises(SystemExit, match="trajectories differ"):
        module_ab.whole_runs(before, module_ab.load_copy(changed, "desc_x"), path, pairs=1)
