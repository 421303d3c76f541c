"""benchmarks/shift_probe.py: the rows that vary one knob of a method compose as uss-train
overrides with the intended values."""

from __future__ import annotations

from shared_helpers import compose_train
from shift_probe import knob_overrides


def test_knob_rows_scale_the_methods_defaults() -> None:
    assert knob_overrides("adaptsegnet+adv30") == [
        "model/method=adaptsegnet",
        "model.loss.lambda_adv_aux=0.06",
        "model.loss.lambda_adv_main=0.3",
    ]
    assert knob_overrides("advent+dlr10") == ["model/method=advent", "model.d_optimizer.lr=0.001"]
    assert knob_overrides("minent+ent0.5")[1:] == [
        "model.method.lambda_ent_aux=0.005",
        "model.method.lambda_ent_main=0.025",
    ]
    assert knob_overrides("adaptsegnet") is None
    assert knob_overrides("adaptsegnet+srcbn") is None


def test_knob_bases_are_the_configs_defaults(tmp_path) -> None:
    """The factors multiply what the shipped configs hold: a change there must show here."""
    adv = compose_train(["experiment=demo", "model/method=adaptsegnet"], tmp_path / "a")
    ent = compose_train(["experiment=demo", "model/method=minent"], tmp_path / "m")
    one = knob_overrides("adaptsegnet+adv1") + knob_overrides("minent+ent1")[1:]
    values = {o.split("=")[0]: float(o.split("=")[1]) for o in one if "=" in o and "." in o}
    assert values["model.loss.lambda_adv_aux"] == adv.model.loss.lambda_adv_aux
    assert values["model.loss.lambda_adv_main"] == adv.model.loss.lambda_adv_main
    assert values["model.method.lambda_ent_aux"] == ent.model.method.lambda_ent_aux
    assert values["model.method.lambda_ent_main"] == ent.model.method.lambda_ent_main
    assert float(knob_overrides("adaptsegnet+dlr1")[1].split("=")[1]) == adv.model.d_optimizer.lr
