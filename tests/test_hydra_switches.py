"""Hydra's own switches (``--experimental-rerun``, ``--cfg job --package``) in the project's
line form, for every Hydra app: no library warning before the one line, no bare Hydra text."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
from hydra.core.global_hydra import GlobalHydra
from test_cli_matrix import run_console_script
from test_path_families import _run

HYDRA_APPS = ("uss-slam", "uss-train", "uss-export", "uss-experiments")


@pytest.mark.parametrize("prog", HYDRA_APPS)
def test_experimental_rerun_of_a_missing_file_is_one_line_without_hydras_warning(
    prog: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """Hydra warned that the option is experimental (a ``UserWarning`` and its source line)
    before the one line naming the switch."""
    monkeypatch.chdir(tmp_path)
    missing = tmp_path / "config.pickle"
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        code, err = _run(prog, ["--experimental-rerun", str(missing)], monkeypatch, capsys)
    assert [str(w.message) for w in seen if "rerun" in str(w.message).lower()] == []
    assert code == 1
    assert err.splitlines() == [
        f"{prog}: error: --experimental-rerun={missing}: File {missing} does not exist"
    ]


def test_experimental_rerun_with_overrides_warns_that_they_change_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """Hydra ignores overrides given beside ``--experimental-rerun``: one warning line of the
    project's form names them (Hydra's was a ``UserWarning``), before the file's own line."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "config.pickle").write_bytes(b"not a pickle")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        argv = ["--experimental-rerun", "config.pickle", "progress=false"]
        code, err = _run("uss-slam", argv, monkeypatch, capsys)
    assert [str(w.message) for w in seen if "overrides" in str(w.message).lower()] == []
    lines = err.splitlines()
    assert code == 1 and len(lines) == 2, err
    assert lines[0] == (
        "uss-slam: warning: progress=false: set but change nothing with --experimental-rerun "
        "(the recorded config runs as it was)"
    )
    assert lines[1].startswith("uss-slam: error: --experimental-rerun=config.pickle: "), err


@pytest.mark.parametrize("prog", HYDRA_APPS)
def test_cfg_package_of_a_missing_key_is_one_line_naming_the_switch(
    prog: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``--cfg job --package nope``: Hydra wrote ``package 'nope' not found in config`` without
    the ``<prog>: error:`` prefix."""
    monkeypatch.chdir(tmp_path)
    code, err = _run(prog, ["--cfg", "job", "--package", "nope"], monkeypatch, capsys)
    assert code == 1
    assert err.splitlines() == [
        f"{prog}: error: --package=nope: not found in the config; expected a key of it "
        "(--cfg job without --package prints them)"
    ]


def test_cfg_package_of_a_key_prints_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    code, out, err = run_console_script(
        "uss-slam", ["--cfg", "job", "--package", "slam.orb"], monkeypatch, capsys
    )
    GlobalHydra.instance().clear()
    assert (code, err) == (0, "")
    assert out.startswith("# @package slam.orb\nn_features: ")


def test_a_home_folder_starting_a_hydra_value_is_expanded_as_a_shell_would(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``key=~/x`` (``sh``, or quoted), list items, a sweep's values and ``--config-dir``: one
    rule for every key; a switch's own value, ``~key`` (Hydra's deletion) and an unknown user
    stay as they are."""
    from uss_slam.core.hydra_lines import home_expanded_argv

    monkeypatch.setenv("HOME", "/h/me")
    argv = ["out_dir=~/x", "sequence.path='~/s 1'", "data.target.roots=[~/a,'~/b',c]",
            "out_dir=~/p,~/q", "--config-dir", "~/c", "--config-dir=~/d", "-p", "~x", "~key",
            "~key=~/z", "a=~nosuchuser-uss/x", "b=x~", "c=~"]  # fmt: skip
    assert home_expanded_argv(argv) == [
        "out_dir=/h/me/x", "sequence.path='/h/me/s 1'", "data.target.roots=[/h/me/a,/h/me/b,c]",
        "out_dir=/h/me/p,/h/me/q", "--config-dir", "/h/me/c", "--config-dir=/h/me/d", "-p", "~x",
        "~key", "~key=/h/me/z", "a=~nosuchuser-uss/x", "b=x~", "c=/h/me",
    ]  # fmt: skip


def test_an_unknown_user_is_one_line_naming_the_key(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``out_dir=~nosuchuser/x`` unquoted: Hydra's lexer refuses the ``~``; the line says why."""
    monkeypatch.chdir(tmp_path)
    code, err = _run("uss-slam", ["out_dir=~nosuchuser-uss/x"], monkeypatch, capsys)
    assert code == 1
    assert err.splitlines() == [
        "uss-slam: error: out_dir: the value '~nosuchuser-uss/x' starts with '~', and this "
        "system has no user 'nosuchuser-uss'; expected ~/..., ~USER/... or the path written out"
    ]


@pytest.mark.parametrize("prog", HYDRA_APPS)
def test_a_config_dir_that_is_no_folder_is_the_path_layers_line(
    prog: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``--config-dir`` names a file or nothing: Hydra's ``Additional config directory ... not
    found`` did not name the switch; the path layer's line does, as for every path."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("")
    code, err = _run(prog, ["--config-dir", "afile"], monkeypatch, capsys)
    assert (code, err.splitlines()) == (
        1, [f"{prog}: error: --config-dir=afile: is a file; expected a folder"]
    )  # fmt: skip
    code, err = _run(prog, ["--config-dir=nope"], monkeypatch, capsys)
    assert (code, err.splitlines()) == (
        1, [f"{prog}: error: --config-dir=nope: does not exist; expected a folder of config files"]
    )  # fmt: skip


@pytest.mark.parametrize("prog", HYDRA_APPS)
def test_a_byte_order_mark_hiding_a_package_header_is_one_line(
    prog: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """A user's config saved with a byte-order mark before ``# @package _global_``: Hydra
    missed the header and put the config under its group (its own text, or ``unknown key``
    later); now one line names the file, before any work."""
    monkeypatch.chdir(tmp_path)
    own = tmp_path / "conf" / "experiment"
    own.mkdir(parents=True)
    bad = own / "mine.yaml"
    bad.write_bytes(b"\xef\xbb\xbf# @package _global_\nprogress: false\n")
    (own / "fine.yaml").write_bytes(b"\xef\xbb\xbfprogress: false\n")  # no header: YAML skips it
    code, err = _run(prog, ["--config-dir", str(tmp_path / "conf")], monkeypatch, capsys)
    assert code == 1
    assert err.splitlines() == [
        f"{prog}: error: {bad}:1: starts with a UTF-8 byte-order mark, which hides its "
        "'# @package' line from Hydra (the config would land under its group); save the file "
        "without it"
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["conf"]


def test_a_config_folder_without_a_hidden_header_passes(tmp_path: Path) -> None:
    from uss_slam.core.hydra_lines import hidden_package_header

    (tmp_path / "a.yaml").write_bytes(b"# @package _global_\nx: 1\n")
    (tmp_path / "b.yaml").write_bytes(b"\xef\xbb\xbfx: 1\n# @package _global_\n")  # not a header
    assert hidden_package_header(tmp_path) is None


@pytest.mark.parametrize("prog", HYDRA_APPS)
def test_package_without_cfg_is_refused_before_the_run(
    prog: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``-p KEY`` without ``--cfg``: Hydra ignored it and ran (a run the user did not mean to
    start, its outputs written); one line naming the switch, nothing written."""
    monkeypatch.chdir(tmp_path)
    code, err = _run(prog, ["-p", "out_dir"], monkeypatch, capsys)
    assert code == 1
    assert err.splitlines() == [
        f"{prog}: error: --package=out_dir: only used with --cfg, to print that part of the "
        "config (--cfg job --package out_dir); without it the run would ignore it"
    ]
    assert list(tmp_path.iterdir()) == []


def test_a_switch_hydra_refuses_is_the_one_its_text_names(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``--cfg job --package slam --resolve -m``: the line names ``--cfg``, the switch Hydra's
    text is about, not the first switch given (``--package``)."""
    monkeypatch.chdir(tmp_path)
    code, err = _run("uss-slam", ["--cfg", "job", "-p", "slam", "-m"], monkeypatch, capsys)
    assert code == 1
    assert err.splitlines() == [
        "uss-slam: error: --cfg=job: Only one of --run, --multirun, --cfg, --info and "
        "--shell_completion can be specified"
    ]


@pytest.mark.parametrize(
    ("prog", "override", "options"),
    [
        ("uss-slam", "segmenter=null", "labels, none, onnx"),
        (
            "uss-train",
            "model/net=null",
            "deeplab_resnet101, deeplab_resnet50, deeplab_small, pspnet_resnet101, pspnet_small",
        ),  # fmt: skip
        ("uss-export", "model=3", "adversarial, source_only"),
    ],
)
def test_a_config_group_set_to_a_value_that_is_no_option_names_the_group(
    prog: str, override: str, options: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``segmenter=null``: Hydra's ``Config group override must be a string or a list. Got
    NoneType`` named no key; the line names the override and the group's options."""
    monkeypatch.chdir(tmp_path)
    code, err = _run(prog, [override], monkeypatch, capsys)
    group = override.partition("=")[0]
    assert code == 1
    assert err.splitlines() == [
        f"{prog}: error: {override}: {group} is a config group; expected one of its options: "
        f"{options}"
    ]
    assert list(tmp_path.iterdir()) == []


def test_a_list_of_another_scripts_overrides_may_be_typed_unquoted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``train.overrides=[model.max_iters=5]``: Hydra's lexer refused the ``=`` in the item;
    the list is read as its quoted form (``--cfg job`` shows what the run would use)."""
    monkeypatch.chdir(tmp_path)
    argv = [
        "--cfg",
        "job",
        "-p",
        "train.overrides",
        "train.overrides=[model.max_iters=5,logger=none]",
    ]
    try:
        code, out, err = run_console_script("uss-experiments", argv, monkeypatch, capsys)
    finally:
        GlobalHydra.instance().clear()
    assert code == 0, err
    assert out.splitlines()[-2:] == ["- model.max_iters=5", "- logger=none"]
