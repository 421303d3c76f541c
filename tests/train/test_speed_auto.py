"""``trainer.precision=auto`` (``trainer=fast_cpu``): bfloat16 only on CPUs built for it."""

from __future__ import annotations

from pathlib import Path

import pytest

from uss_slam.train.speed import cpu_flags, fast_cpu_bf16, resolve_precision

AVX2_ONLY = {"sse4_2", "avx", "avx2", "fma"}
ZEN4 = AVX2_ONLY | {"avx512f", "avx512_bf16"}
SAPPHIRE_RAPIDS = AVX2_ONLY | {"avx512f", "amx_tile", "amx_bf16"}


@pytest.mark.parametrize(
    ("flags", "expected", "said"),
    [
        (AVX2_ONLY, "32-true", "neither AVX512-BF16 nor AMX"),
        (ZEN4, "bf16-mixed", "this CPU has avx512_bf16"),
        (SAPPHIRE_RAPIDS, "bf16-mixed", "this CPU has amx_bf16"),
    ],
)
def test_auto_picks_by_the_cpu(flags: set[str], expected: str, said: str) -> None:
    precision, reason = resolve_precision("auto", "cpu", flags)
    assert precision == expected
    assert reason is not None and said in reason and expected in reason
    assert fast_cpu_bf16(flags) == (expected == "bf16-mixed")


def test_explicit_precision_is_kept() -> None:
    assert resolve_precision("bf16-mixed", "cpu", AVX2_ONLY) == ("bf16-mixed", None)
    assert resolve_precision("32-true", "cpu", ZEN4) == ("32-true", None)


def test_cpuinfo_parsing(tmp_path: Path) -> None:
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: X\nflags\t\t: fpu avx2 avx512_bf16\n\n"
                    "processor\t: 1\nflags\t\t: fpu avx2 avx512_bf16\n")  # fmt: skip
    assert cpu_flags(info) == {"fpu", "avx2", "avx512_bf16"}
    assert cpu_flags(tmp_path / "absent") == set()


def test_fast_cpu_asks_for_auto() -> None:
    from hydra import compose, initialize_config_dir

    config_dir = Path(__file__).resolve().parents[2] / "configs"
    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3"):
        cfg = compose("train", overrides=["experiment=ci", "trainer=fast_cpu"])
    assert cfg.trainer.precision == "auto"
    assert cfg.model.channels_last is True
