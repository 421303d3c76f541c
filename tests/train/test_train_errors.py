"""``uss-train`` as a user runs it (its console-script ``main``, in this process): every user
error is exit code 1 and one line on stderr naming the key or file, found before the trainer
starts, leaving no checkpoints or logs behind; a multirun's failing job does not stop the
others (``uss-train -m`` and ``uss-slam -m``)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from hydra.utils import instantiate
from PIL import Image
from shared_helpers import compose_train, data_overrides

from uss_slam.train import train as train_cli

HYDRA_FILES = {".hydra", "train.log"}


def _cli(
    main, prog: str, args: list[str], monkeypatch: pytest.MonkeyPatch, capsys
) -> tuple[int, list[str]]:
    """Exit code and stderr lines of ``main()`` with ``args`` on the command line."""
    monkeypatch.setattr(sys, "argv", [prog, *args])
    capsys.readouterr()
    try:
        main()
        code = 0
    except SystemExit as done:
        code = int(done.code or 0)
    return code, capsys.readouterr().err.strip().splitlines()


def _uss_train(args: list[str], monkeypatch, capsys) -> tuple[int, list[str]]:
    return _cli(train_cli.main, "uss-train", args, monkeypatch, capsys)


def _common(data: dict[str, Path], tmp_path: Path) -> list[str]:
    return [
        "experiment=ci",
        *data_overrides(data),
        f"hydra.run.dir={tmp_path / 'run'}",
        f"paths.log_dir={tmp_path / 'logs'}",
    ]


def _left_behind(run: Path) -> set[str]:
    """What the failed run wrote besides Hydra's config record and log."""
    return {p.name for p in run.iterdir()} - HYDRA_FILES if run.exists() else set()


def _checkpoint(tmp_path: Path, name: str, overrides: list[str]) -> Path:
    """A checkpoint in uss-train's format (weights of the ``ci`` model built with
    ``overrides``), without training."""
    cfg = compose_train(["experiment=ci", *overrides], tmp_path / "build")
    model = instantiate(cfg.model)
    path = tmp_path / name
    torch.save(
        {
            "state_dict": model.state_dict(),
            "hyper_parameters": dict(model.hparams),
            "iteration": 2,
        },
        path,
    )
    return path


def _bad_checkpoint(kind: str, tmp_path: Path) -> tuple[Path, str]:
    if kind == "truncated":
        path = _checkpoint(tmp_path, "truncated.ckpt", [])
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
        return path, "not a readable checkpoint"
    if kind == "random":
        path = tmp_path / "random.ckpt"
        path.write_bytes(torch.randint(0, 256, (4096,), dtype=torch.uint8).numpy().tobytes())
        return path, "not a readable checkpoint"
    if kind == "not_lightning":
        path = tmp_path / "weights.pth"
        torch.save({"conv.weight": torch.zeros(2, 2)}, path)
        return path, "not a Lightning checkpoint"
    if kind == "classes":
        overrides = ["model.net.num_classes=3", "model.class_names=[background,person,chair]"]
        return _checkpoint(tmp_path, "three.ckpt", overrides), "checkpoint has 3 classes"
    if kind == "architecture":
        overrides = ["model.method.discriminator.n_layers=5"]
        return _checkpoint(tmp_path, "deeper.ckpt", overrides), "d_aux.layers"
    raise AssertionError(kind)


@pytest.mark.parametrize(
    "kind", ["truncated", "random", "not_lightning", "classes", "architecture"]
)
def test_bad_checkpoint_is_one_line_before_the_trainer_starts(
    kind: str, uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    path, expected = _bad_checkpoint(kind, tmp_path)
    before = path.read_bytes()
    code, err = _uss_train([*_common(uda_data, tmp_path), f"ckpt_path={path}"], monkeypatch, capsys)
    assert code == 1
    assert len(err) == 1, err
    assert err[0].startswith("uss-train: error: ") and str(path) in err[0] and expected in err[0]
    assert _left_behind(tmp_path / "run") == set()  # no checkpoints/, tensorboard/, manifest
    assert path.read_bytes() == before


@pytest.mark.parametrize(
    ("override", "line"),
    [
        ("model.max_iters=abc", "model.max_iters: expected an integer >= 1, got 'abc'"),
        ("trainer.max_epochs=x", "trainer.max_epochs: expected an integer >= -1 or null, got 'x'"),
        ("model.optimizer.lr=fast", "model.optimizer.lr: expected a number >= 0, got 'fast'"),
        ("model.net.num_classes=2.5", "model.net.num_classes: expected an integer, got 2.5"),
        ("model.batch_domains=maybe", "model.batch_domains: expected true or false, got 'maybe'"),
        (
            "model.domain_batch_norm=both",
            "model.domain_batch_norm: expected one of 'separate', 'joint', 'running', got 'both'",
        ),
    ],
)
def test_wrong_value_type_is_one_line_naming_the_key(
    override: str, line: str, uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    code, err = _uss_train([*_common(uda_data, tmp_path), override], monkeypatch, capsys)
    assert (code, err) == (1, [f"uss-train: error: {line}"])
    assert _left_behind(tmp_path / "run") == set()


def test_unknown_key_is_one_line(uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys):
    code, err = _uss_train([*_common(uda_data, tmp_path), "model.max_iter=3"], monkeypatch, capsys)
    assert code == 1 and len(err) == 1, err
    assert err[0].startswith("uss-train: error: model.max_iter: ")
    assert not (tmp_path / "run").exists()  # Hydra stopped while composing


@pytest.mark.parametrize(
    ("override", "line"),
    [
        (
            "+trainer.gradient_clip_val=1.0",
            "trainer.gradient_clip_val=1.0: the training step optimises its networks itself "
            "(Lightning's manual optimization); Lightning clips no gradients there; expected null",
        ),
        (
            "+trainer.accumulate_grad_batches=2",
            "trainer.accumulate_grad_batches=2: the training step optimises its networks itself "
            "(Lightning's manual optimization); Lightning accumulates no gradients there; "
            "expected 1",
        ),
        (
            "+trainer.enable_checkpointing=false",
            "trainer.enable_checkpointing=false: the callbacks save checkpoints "
            "(ResumableModelCheckpoint, ResumableModelCheckpoint); expected true, or "
            "callbacks=none for a run without them",
        ),
    ],
)
def test_a_trainer_setting_lightning_would_refuse_in_fit_is_one_line(
    override: str, line: str, uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    code, err = _uss_train([*_common(uda_data, tmp_path), override], monkeypatch, capsys)
    assert (code, err) == (1, [f"uss-train: error: {line}"])
    assert _left_behind(tmp_path / "run") == set()


def test_lightning_configuration_errors_name_the_trainer_key() -> None:
    from hydra.errors import InstantiationException
    from lightning.fabric.utilities.exceptions import MisconfigurationException

    from uss_slam.train.trainer_settings import trainer_error

    quoted = MisconfigurationException("Remove `Trainer(gradient_clip_val=1.0)` or switch.")
    wrapped = InstantiationException("Error in call to target")
    wrapped.__cause__ = MisconfigurationException("`enable_checkpointing=False` but found x")
    assert str(trainer_error(quoted)).startswith("trainer.gradient_clip_val: Remove")
    assert str(trainer_error(wrapped)).startswith("trainer.enable_checkpointing: ")
    assert str(trainer_error(MisconfigurationException("no key"))) == "trainer: no key"
    assert trainer_error(ValueError("x")) is None


@pytest.mark.parametrize(
    "key",
    ["hydra.run.dir", "callbacks.model_checkpoint.dirpath", "logger.tensorboard.save_dir"],
)
def test_unwritable_output_folder_is_one_line(
    key: str, uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder\n")
    target = blocker / "out"
    common = [o for o in _common(uda_data, tmp_path) if not o.startswith(f"{key}=")]  # once
    code, err = _uss_train([*common, f"{key}={target}"], monkeypatch, capsys)
    assert code == 1 and len(err) == 1, err
    if key == "hydra.run.dir":
        assert err[0] == (
            f"uss-train: error: hydra.run.dir={target}: cannot create the output folder "
            f"({blocker} is a file); expected a folder to write into"
        )
    else:
        assert (
            err[0] == f"uss-train: error: {key}={target}: cannot create the output folder "
            f"({blocker} is a file); expected a folder to write into"
        )
        assert _left_behind(tmp_path / "run") == set()
    assert blocker.read_text() == "not a folder\n"


# --------------------------------------------------------------------------- multirun


@pytest.mark.slow
def test_train_multirun_jobs_fail_independently(
    uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    sweep = tmp_path / "sweep"
    args = [
        "-m",
        "experiment=ci",
        *data_overrides(uda_data),
        "logger=none",
        "+trainer.limit_val_batches=1",
        "model.max_iters=abc,2",
        f"hydra.sweep.dir={sweep}",
        f"paths.log_dir={tmp_path / 'logs'}",
    ]
    code, err = _uss_train(args, monkeypatch, capsys)
    line = "uss-train: error: model.max_iters: expected an integer >= 1, got 'abc'"
    assert code == 1
    assert err == [line, "uss-train: 1 of 2 jobs failed:", f"  #0 model.max_iters=abc: {line}"]
    # The bad job left nothing; the good one trained to the end.
    assert _left_behind(sweep / "0") == set()
    assert "model.max_iters=2" in yaml.safe_load(
        (sweep / "1" / ".hydra" / "overrides.yaml").read_text()
    )
    state = torch.load(sweep / "1" / "checkpoints" / "last.ckpt", weights_only=True)
    assert state["iteration"] == 2


@pytest.mark.slow
def test_slam_multirun_jobs_fail_independently(
    synthetic_sequence, tmp_path: Path, monkeypatch, capsys
) -> None:
    from uss_slam.slam_eval import run as slam_cli

    seq = synthetic_sequence(preset="walking_xyz", frames=30)
    out = tmp_path / "slam"
    args = [
        "-m",
        f"sequence.path={seq}",
        "sequence.max_frames=8",
        "progress=false",
        f"out_dir={out}",
        "slam.orb.scale_factor=0.9,1.2",
    ]
    code, err = _cli(slam_cli.main, "uss-slam", args, monkeypatch, capsys)
    assert code == 1
    assert len(err) == 3, err
    assert err[0].startswith(
        "uss-slam: error: slam.orb.scale_factor: expected a number > 1.0, got 0.9"
    )
    assert err[1:] == ["uss-slam: 1 of 2 jobs failed:", f"  #0 slam.orb.scale_factor=0.9: {err[0]}"]
    assert (out / "1" / "metrics.json").is_file()
    assert not (out / "0" / "metrics.json").exists()


@pytest.mark.parametrize(
    ("override", "named"),
    [
        ("model.optimizer.lr=0.1", "model.optimizer.lr ("),
        ("model.max_iters=1", "model.max_iters (4 -> 1)"),
        ("model/method=minent", "model/method ('adaptsegnet' -> 'minent')"),
    ],
)
def test_resume_with_other_model_settings_is_one_line(
    override: str, named: str, uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    """A resumed run keeps the checkpoint's optimiser, method and schedule: another value is
    refused (naming the key, both values) before the trainer starts, instead of being ignored
    (a new lr) or ending the run at once (a smaller max_iters)."""
    path = _checkpoint(tmp_path, "earlier.ckpt", [])
    before = path.read_bytes()
    args = [*_common(uda_data, tmp_path), f"ckpt_path={path}", override]
    code, err = _uss_train(args, monkeypatch, capsys)
    assert code == 1 and len(err) == 1, err
    assert err[0].startswith(f"uss-train: error: ckpt_path {path}: expected the checkpoint's")
    assert named in err[0], err[0]
    assert _left_behind(tmp_path / "run") == set()
    assert path.read_bytes() == before


def test_resume_with_the_same_model_settings_passes_the_check(
    uda_data: dict[str, Path], tmp_path: Path
) -> None:
    """Trainer, logging and thread settings may change on resume; the model's may not."""
    from uss_slam.train.module import resume_differences

    cfg = compose_train(["experiment=ci"], tmp_path / "a")
    saved = dict(instantiate(cfg.model).hparams)
    again = compose_train(["experiment=ci", "trainer.max_epochs=7", "num_threads=1"], tmp_path)
    assert resume_differences(saved, dict(instantiate(again.model).hparams)) == []
    other = compose_train(["experiment=ci", "model.method.lambda_adv_main=0.5"], tmp_path / "b")
    assert resume_differences(saved, dict(instantiate(other.model).hparams)) == [
        "model.method.lambda_adv_main (0.01 -> 0.5)"
    ]


def test_a_full_disk_while_saving_a_checkpoint_names_it_and_leaves_no_part(
    uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    """Checkpoints are written beside their final name and renamed: a full disk is one line
    naming the checkpoints folder's key and the checkpoint's own path, and no truncated ``.ckpt``,
    temporary file or new empty folder is left."""
    from shared_helpers import full_disk

    hit = full_disk(monkeypatch, lambda path: path.suffix == ".ckpt")
    code, err = _uss_train([*_common(uda_data, tmp_path), "logger=none"], monkeypatch, capsys)
    assert hit, "no checkpoint was written"
    assert code == 1, err
    folder = tmp_path / "run" / "checkpoints"  # the key that sets it (under hydra.run.dir)
    assert err[-1] == (
        f"uss-train: error: callbacks.last_checkpoint.dirpath={folder}: no space left on device "
        f"while writing {hit[0]}"
    ), err
    assert "Traceback" not in "\n".join(err)
    folder = tmp_path / "run" / "checkpoints"
    assert hit[0].parent == folder
    assert not folder.exists()  # the failed write removes the folder it made for its file


def _damage(kind: str, data: dict[str, Path]) -> Path:
    """Damage one file of the ``uda_data`` copy: a VOC label value 40 (no VOC class), a
    validation label value 4 (no class id), a VOC JPEG cut in half; returns the file."""
    if kind == "val_label_4":
        path = sorted((data["val"] / "labels").glob("*.png"))[-1]
        values = np.array(Image.open(path))
        values[0, 0] = 4
        Image.fromarray(values).save(path)
        return path
    voc = next(data["voc"].rglob("SegmentationClass")).parent
    if kind == "voc_label_40":
        path = sorted((voc / "SegmentationClass").glob("*.png"))[-1]
        label = Image.open(path)
        values = np.array(label)
        values[0, 0] = 40
        out = Image.fromarray(values, mode="P")
        out.putpalette(label.getpalette())
        out.save(path)
        return path
    path = sorted((voc / "JPEGImages").glob("*.jpg"))[-1]
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    return path


@pytest.mark.parametrize(
    ("kind", "reason"),
    [
        ("voc_label_40", "label values [40]"),
        ("val_label_4", "label values 4 are not class ids"),
        ("voc_jpeg_cut", "truncated JPEG"),
    ],
)
def test_a_bad_label_or_image_is_one_line_before_lightning_starts(
    kind: str, reason: str, uda_data: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    """Found by the up-front check of the data's files (``datasets.precheck``), not by the
    batch that would read it after Lightning's device lines (or by none)."""
    data = {
        key: Path(shutil.copytree(root, tmp_path / "data" / key)) for key, root in uda_data.items()
    }
    path = _damage(kind, data)
    code, err = _uss_train(_common(data, tmp_path), monkeypatch, capsys)
    assert code == 1 and len(err) == 1, err
    assert err[0].startswith("uss-train: error: data.") and path.name in err[0] and reason in err[0]
    assert _left_behind(tmp_path / "run") == set()
