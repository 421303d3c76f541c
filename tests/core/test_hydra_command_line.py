"""What a Hydra app's command line may hold beyond plain values: an interpolation that cannot
be resolved (``${oc.env:X}`` unset, ``${nope}``) is one line naming the key that holds it, also
in the run folder's key (``out_dir=${nope}``)."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from uss_slam.core.errors import UssSlamError
from uss_slam.core.run_folders import RefusedRunFolder, RunFolderCheck
from uss_slam.core.schema.compose import check_interpolations


def test_an_unset_variable_names_its_key(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("USS_TEST_UNSET", raising=False)
    monkeypatch.setenv("USS_TEST_SET", "/data/seq")
    cfg = OmegaConf.create({"sequence": {"path": "${oc.env:USS_TEST_SET}", "start": 0},
                            "segmenter": {"path": "${oc.env:USS_TEST_UNSET}"}, "x": "???"})  # fmt: skip
    with pytest.raises(UssSlamError) as error:
        check_interpolations(cfg)
    assert str(error.value) == (
        "segmenter.path: cannot resolve ${oc.env:USS_TEST_UNSET} "
        "(Environment variable 'USS_TEST_UNSET' not found)"
    )
    cfg.segmenter.path = "${sequence.path}"
    check_interpolations(cfg)  # resolvable, and the missing value is the schema's business


def test_a_missing_key_in_a_list_names_its_index() -> None:
    cfg = OmegaConf.create({"data": {"roots": ["/a", "${nope}"]}})
    with pytest.raises(UssSlamError, match=r"^data\.roots\[1\]: cannot resolve \$\{nope\}"):
        check_interpolations(cfg)


def test_a_run_folder_that_cannot_be_resolved_names_the_apps_key() -> None:
    config = OmegaConf.create({"out_dir": "${nope}", "hydra": {"run": {"dir": "${out_dir}"}}})
    with pytest.raises(RefusedRunFolder) as refused:
        RunFolderCheck("uss-slam", "out_dir").on_run_start(config)
    assert str(refused.value.error).startswith("out_dir: Interpolation key 'nope' not found")


def test_lightnings_ddp_tail_is_not_a_key_given_twice() -> None:
    """Lightning's DDP launcher starts each process with the parent's command line and its own
    ``hydra.run.dir`` / ``hydra.job.name`` / ``hydra.output_subdir``: not the user's repeat."""
    from uss_slam.core.hydra_lines import repeated_override_line

    user = ["experiment=ci", "trainer=ddp_cpu", "hydra.run.dir=/runs/a"]
    child = [*user, 'hydra.run.dir="/runs/a"', "hydra.job.name=train_ddp_process_1",
             "hydra.output_subdir=null"]  # fmt: skip
    assert repeated_override_line(child) is None
    twice = ["hydra.run.dir=/runs/b", *child]  # the user's own repeat is still refused
    assert repeated_override_line(twice) == (
        "hydra.run.dir: given twice on the command line (hydra.run.dir=/runs/b and "
        "hydra.run.dir=/runs/a); expected each key once (Hydra would keep the last one without "
        "a word)"
    )
    assert repeated_override_line([*user, "hydra.run.dir=/runs/c"]) is not None
