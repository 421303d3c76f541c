"""benchmarks/slam_backend.py: a run's line says what local BA did, also when it never ran."""

from __future__ import annotations

from slam_backend import _local_ba_text


def test_local_ba_text_for_every_kind_of_run() -> None:
    assert _local_ba_text({"local_ba_ms": None, "local_ba_cpu_ms": None}) == ""  # no local BA
    # a still camera makes one keyframe: local BA is on but never runs (it crashed the line)
    never = {"local_ba_ms": 0.0, "local_ba_cpu_ms": None}
    assert _local_ba_text(never) == "  local BA never ran (one keyframe)"
    ran = {"local_ba_ms": 310.4, "local_ba_cpu_ms": 69.2}
    assert _local_ba_text(ran) == "  local BA 69 ms CPU (310 wall)"
