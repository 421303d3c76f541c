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


@pytest.mark.parametrize(
    "value",
    ["${oops}", "${oc.env:HOME}", r"a\b", "x y", "[1,2]", "{a: 1}", "a=b", "(t)", "\t", "plain"],
)
def test_a_job_override_is_shown_as_typed(value: str) -> None:
    from hydra._internal.grammar.utils import escape_special_characters

    from uss_slam.core.hydra_lines import as_typed

    escaped = f"key={escape_special_characters(value)}"  # as Hydra's sweeper hands it to a job
    assert as_typed(escaped) == f"key={value}"
    assert as_typed(r"key='$\{kept\}'") == r"key='$\{kept\}'"  # quoted: Hydra escapes nothing


def test_the_failed_jobs_of_a_multirun_are_listed_as_typed(
    tmp_path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Hydra's sweeper escapes ``\\()[]{}:=,`` space and tab in each job's overrides
    (``$\\{oops\\}``); the list of failed jobs shows them as the user typed them."""
    import sys

    from uss_slam.slam_eval import run as slam_cli

    monkeypatch.chdir(tmp_path)
    argv = ["-m", "sequence.path=/nonexistent,${oops}", f"out_dir={tmp_path / 'sweep'}"]
    monkeypatch.setattr(sys, "argv", ["uss-slam", *argv, "progress=false"])
    with pytest.raises(SystemExit) as stop:
        slam_cli.main()
    err = capsys.readouterr().err.strip().splitlines()
    assert stop.value.code == 1, err
    assert err[-3] == "uss-slam: 2 of 2 jobs failed:", err
    assert err[-2].startswith("  #0 sequence.path=/nonexistent: uss-slam: error: ")
    assert err[-1].startswith("  #1 sequence.path=${oops}: uss-slam: error: sequence.path: "), err
