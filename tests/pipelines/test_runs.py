"""The pieces both drivers share: checkpoint policies, the typed SLAM job and its overrides, and
the one-line errors for bad values."""

from __future__ import annotations

from pathlib import Path

import pytest

from uss_slam.core.errors import UssSlamError
from uss_slam.pipelines import runs
from uss_slam.pipelines.runs import OrbSlam3, Segmenter, SlamJob, Variant


def _checkpoints(run_dir: Path, *names: str) -> None:
    folder = run_dir / "checkpoints"
    folder.mkdir(parents=True)
    for name in names:
        (folder / name).write_bytes(b"")


def test_best_target_val_takes_the_best_checkpoint_else_last(tmp_path: Path) -> None:
    _checkpoints(tmp_path / "a", "last.ckpt", "best_iter000004_miou0.2500.ckpt")
    chosen = runs.select_checkpoint(tmp_path / "a", "best_target_val")
    assert chosen.name == "best_iter000004_miou0.2500.ckpt"
    assert runs.checkpoint_miou(chosen) == 0.25
    _checkpoints(tmp_path / "b", "last.ckpt")
    last = runs.select_checkpoint(tmp_path / "b", "best_target_val")
    assert last.name == "last.ckpt" and runs.checkpoint_miou(last) is None
    _checkpoints(tmp_path / "c")
    with pytest.raises(UssSlamError, match=r"checkpoints: no checkpoint"):
        runs.select_checkpoint(tmp_path / "c", "best_target_val")


def test_the_default_policy_uses_no_target_labels(tmp_path: Path) -> None:
    """The protocol's default is the last checkpoint at the fixed budget, whatever the best
    target-validation one is; the policy that reads target labels is marked as such."""
    _checkpoints(tmp_path / "a", "last.ckpt", "best_iter000004_miou0.2500.ckpt")
    assert runs.DEFAULT_POLICY == "last"
    assert runs.select_checkpoint(tmp_path / "a").name == "last.ckpt"
    assert runs.DEFAULT_POLICY not in runs.USES_TARGET_LABELS
    assert "selected with target labels" in runs.policy_note("best_target_val")
    assert "no target labels" in runs.policy_note("last")
    _checkpoints(tmp_path / "b", "best_iter000004_miou0.2500.ckpt")
    with pytest.raises(UssSlamError, match=r"checkpoints: no last.ckpt after training"):
        runs.select_checkpoint(tmp_path / "b")


def test_a_policy_is_one_function(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _checkpoints(tmp_path, "last.ckpt", "best_iter000002_miou0.1000.ckpt")
    policies = {**runs.CHECKPOINT_POLICIES, "first": lambda d: d / "checkpoints" / "last.ckpt"}
    monkeypatch.setattr(runs, "CHECKPOINT_POLICIES", policies)
    assert runs.select_checkpoint(tmp_path, "first").name == "last.ckpt"
    with pytest.raises(
        UssSlamError, match=r"policy 'oldest': unknown; accepted: last, best_target_val"
    ):
        runs.select_checkpoint(tmp_path, "oldest")


def test_slam_job_overrides_in_uss_slams_order() -> None:
    model = Path("/x/m.onnx")
    plain = SlamJob(Path("/s"), Segmenter.onnx(model), ("semantic", "geometry"))
    assert plain.overrides() == [
        "sequence.path=/s",
        "segmenter=onnx",
        "segmenter.path=/x/m.onnx",
        "filters=[semantic,geometry]",
    ]
    crf = Segmenter.onnx(model, crf=True, crf_params={"iterations": 2})
    orb = SlamJob(
        Path("/s"),
        crf,
        ("semantic",),
        extra=("slam.workers=1",),
        orbslam3=OrbSlam3(Path("/v.txt"), 2),
        max_frames=20,
    )
    assert orb.overrides() == [
        "sequence.path=/s",
        "segmenter=onnx",
        "segmenter.path=/x/m.onnx",
        "segmenter.crf=true",
        "segmenter.crf_params.iterations=2",
        "slam.workers=1",
        "filters=[]",  # ORB-SLAM3 gets the mask blanked out of its input, not the filters
        "system=orbslam3",
        "system.vocabulary=/v.txt",
        "system.repeats=2",
        "sequence.max_frames=20",
    ]
    assert SlamJob.from_json(orb.to_json()) == orb
    assert SlamJob.from_json(plain.to_json()) == plain
    assert SlamJob(Path("/s")).overrides() == ["sequence.path=/s", "segmenter=none", "filters=[]"]


def test_segmenter_of_a_variant() -> None:
    oracle = Variant("oracle", "ground truth", "labels", ("semantic",))
    assert Segmenter.of(oracle) == Segmenter("labels")
    semantic_crf = Variant("s", "s", "model", ("semantic",), crf=True)
    assert Segmenter.of(semantic_crf, Path("m.onnx"), {"iterations": 3}).refinement() == [
        "segmenter.crf=true",
        "segmenter.crf_params.iterations=3",
    ]
    plain = Variant("p", "p", "model", ("semantic",))
    assert Segmenter.of(plain, Path("m.onnx"), {"iterations": 3}).refinement() == []
    with pytest.raises(UssSlamError, match=r"variant p: needs an exported model"):
        Segmenter.of(plain)


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: Variant("v", "v", "onnx"), r"variant v: segmenter 'onnx'; expected one of"),
        (lambda: Variant("v", "v", "labels", crf=True), r"variant v: the dense CRF needs"),
        (lambda: Segmenter("model"), r"segmenter 'model': expected none, labels or onnx"),
        (lambda: Segmenter("onnx"), r"segmenter onnx: a path is for \(and only for\) onnx"),
        (lambda: Segmenter("none", Path("m")), r"segmenter none: a path is for"),
        (lambda: Segmenter("labels", crf=True), r"segmenter labels: the dense CRF refines"),
        (lambda: SlamJob.from_json({"sequence": "/s"}, "plan.json"), r"plan.json: not a SLAM job"),
    ],
)
def test_bad_values_are_one_line(build, message: str) -> None:
    with pytest.raises(UssSlamError, match=message):
        build()


def test_the_slam_defaults_key_ignores_what_changes_only_the_time(monkeypatch) -> None:
    """``slam.reuse_labels`` changes no trajectory: SLAM runs made with either value stay
    valid. A setting that changes the run does change the key."""
    compose = runs.compose_slam

    def key_with(name: str, value) -> str:
        def composed(*args, **kwargs):
            cfg = compose(*args, **kwargs)
            assert name in cfg.slam  # the key still names a real setting
            cfg.slam[name] = value
            return cfg

        monkeypatch.setattr(runs, "compose_slam", composed)
        return runs.slam_defaults_key.__wrapped__()

    plain = runs.slam_defaults_key.__wrapped__()
    assert key_with("reuse_labels", False) == plain == key_with("reuse_labels", True)
    assert key_with("repeat_seed", 5) != plain
