"""studies/shift_probe.py: the rows that vary one knob of a method compose as uss-train
overrides with the intended values."""

from __future__ import annotations

from pathlib import Path

import pytest
from shared_helpers import compose_train

from uss_slam.testing.scripts import load_script

shift_probe = load_script(Path(__file__).resolve().parents[2] / "studies" / "shift_probe.py")
knob_overrides = shift_probe.knob_overrides


def test_knob_rows_scale_the_methods_defaults() -> None:
    assert knob_overrides("adaptsegnet+adv30") == [
        "model/method=adaptsegnet",
        "model.method.lambda_adv_aux=0.06",
        "model.method.lambda_adv_main=0.3",
    ]
    assert knob_overrides("advent+dlr10") == [
        "model/method=advent",
        "model.method.d_optimizer.lr=0.001",
    ]
    assert knob_overrides("source_only+lr3") == [
        "model/method=source_only",
        "model.optimizer.lr=0.03",
    ]
    assert knob_overrides("minent+ent0.5")[1:] == [
        "model.method.lambda_ent_aux=0.005",
        "model.method.lambda_ent_main=0.025",
    ]
    assert knob_overrides("adaptsegnet") == ["model/method=adaptsegnet"]
    assert knob_overrides("adaptsegnet+srcbn")[1:] == ["callbacks.precise_bn.domain=source"]
    assert knob_overrides("adaptsegnet+running+adv10") == [
        "model/method=adaptsegnet",
        "model.domain_batch_norm=running",
        "model.method.lambda_adv_aux=0.02",
        "model.method.lambda_adv_main=0.1",
    ]


def test_the_threshold_knob_sets_self_trainings_confidence(tmp_path) -> None:
    rows = knob_overrides("self_training+thr0.9")
    assert rows == ["model/method=self_training", "model.method.pseudo_threshold=0.9"]
    cfg = compose_train(["experiment=demo", *rows], tmp_path / "st")
    assert cfg.model.method.pseudo_threshold == 0.9
    with pytest.raises(SystemExit, match="'thr1.5' in 'self_training\\+thr1.5'.*in \\(0, 1\\)"):
        knob_overrides("self_training+thr1.5")


def test_unknown_knob_names_the_row() -> None:
    with pytest.raises(SystemExit, match="unknown knob 'fast' in 'adaptsegnet\\+fast'"):
        knob_overrides("adaptsegnet+fast")


def test_every_knob_composes(tmp_path) -> None:
    for row in ("adaptsegnet+joint", "adaptsegnet+running+dlr10", "adaptsegnet+srcbn"):
        cfg = compose_train(["experiment=demo", *knob_overrides(row)], tmp_path / row)
        assert cfg.model.method._target_.endswith("AdaptSegNet")
    assert cfg.callbacks.precise_bn.domain == "source"


def test_knob_bases_are_the_configs_defaults(tmp_path) -> None:
    """The factors multiply what the shipped configs hold: a change there must show here."""
    adv = compose_train(["experiment=demo_scratch", "model/method=adaptsegnet"], tmp_path / "a")
    ent = compose_train(["experiment=demo_scratch", "model/method=minent"], tmp_path / "m")
    one = knob_overrides("adaptsegnet+adv1") + knob_overrides("minent+ent1")[1:]
    values = {o.split("=")[0]: float(o.split("=")[1]) for o in one if "=" in o and "." in o}
    assert values["model.method.lambda_adv_aux"] == adv.model.method.lambda_adv_aux
    assert values["model.method.lambda_adv_main"] == adv.model.method.lambda_adv_main
    assert values["model.method.lambda_ent_aux"] == ent.model.method.lambda_ent_aux
    assert values["model.method.lambda_ent_main"] == ent.model.method.lambda_ent_main
    assert (
        float(knob_overrides("adaptsegnet+dlr1")[1].split("=")[1])
        == adv.model.method.d_optimizer.lr
    )
    assert float(knob_overrides("source_only+lr1")[1].split("=")[1]) == adv.model.optimizer.lr


def test_a_folder_without_a_data_set_is_named(tmp_path, monkeypatch) -> None:
    argv = ["shift_probe.py", "--data", str(tmp_path), "--test", str(tmp_path), "--runs",
            str(tmp_path / "runs")]  # fmt: skip
    monkeypatch.setattr("sys.argv", argv)
    with pytest.raises(SystemExit, match=f"--data {tmp_path}: no demo.yaml .*--render SHIFT"):
        shift_probe.main()
    monkeypatch.setattr("sys.argv", [*argv, "--render", "sideways"])
    with pytest.raises(SystemExit):  # argparse: invalid choice
        shift_probe.main()


def _scores(miou: float) -> dict:
    return {"test": {"mIoU": miou, "person": miou / 2}, "train_cpu_s": 1.0}


def test_the_table_pairs_every_row_by_seed(tmp_path, monkeypatch, capsys) -> None:
    import json

    a = {"source_only": {"0": _scores(0.2), "1": _scores(0.3)},
         "adabn": {"0": _scores(0.4), "1": _scores(0.4)},
         "oracle": {"0": _scores(0.6), "1": _scores(0.7)}}  # fmt: skip
    b = {"adaptsegnet": {"0": _scores(0.5), "1": _scores(0.35), "2": _scores(0.9)}}
    (tmp_path / "a.json").write_text(json.dumps(a))
    (tmp_path / "b.json").write_text(json.dumps(b))
    argv = ["shift_probe.py", "--test", "test", "--runs", str(tmp_path / "out"),
            "--merge", str(tmp_path / "a.json"), "--merge", str(tmp_path / "b.json")]  # fmt: skip
    monkeypatch.setattr("sys.argv", argv)
    shift_probe.main()
    rows = {line.split(" | ")[0][2:]: line.split(" | ")
            for line in (tmp_path / "out" / "probe.md").read_text().splitlines()[4:]}  # fmt: skip
    # adaptsegnet: seeds 0 and 1 are paired (seed 2 has no reference): +0.3 and +0.05
    assert rows["adaptsegnet"][3] == "0.175 ± 0.125 (2/2 above)"
    # against AdaBN: +0.1 and -0.05
    assert rows["adaptsegnet"][4] == "0.025 ± 0.075 (1/2 above)"
    # closure (0.5-0.2)/(0.6-0.2) = 0.75 and (0.35-0.3)/(0.7-0.3) = 0.125
    assert rows["adaptsegnet"][5] == "0.438 ± 0.312 |"
    assert rows["source_only"][3] == "—"
    assert json.loads((tmp_path / "out" / "probe.json").read_text())["adaptsegnet"]["2"]
    capsys.readouterr()


def test_a_merge_file_that_is_not_a_probe_is_named(tmp_path, monkeypatch) -> None:
    (tmp_path / "bad.json").write_text("[1, 2]")
    monkeypatch.setattr("sys.argv", ["shift_probe.py", "--test", "t", "--runs", str(tmp_path),
                                     "--merge", str(tmp_path / "bad.json")])  # fmt: skip
    with pytest.raises(SystemExit, match="bad.json: expected"):
        shift_probe.main()


def test_discriminator_accuracy_is_the_last_quarter_of_the_log(tmp_path) -> None:
    discriminator_accuracy = shift_probe.discriminator_accuracy

    (tmp_path / "csv").mkdir()
    lines = ["step,train/d_acc_main,train/d_acc_aux,val/mIoU"]
    lines += [f"{s},{0.5 if s < 75 else 0.9},{0.5},"for s in range(0, 100, 5)]  # fmt: skip
    lines += ["100,,,0.3"]  # a validation row: no accuracy
    (tmp_path / "csv" / "metrics.csv").write_text("\n".join(lines) + "\n")
    # logged steps 0..95: the last quarter is steps >= 0.75 * 95 = 71.25, i.e. 75..95
    assert discriminator_accuracy(tmp_path) == {"d_acc_main": 0.9, "d_acc_aux": 0.5}
    assert discriminator_accuracy(tmp_path / "none") == {}
