"""Fixtures of the export tests: ``uss_export`` runs the console script in this process."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from uss_slam.export import cli as export_cli

Runner = Callable[..., tuple[int, str, str]]


@pytest.fixture
def uss_export(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> Runner:
    """``uss_export(*overrides) -> (exit code, stdout, stderr)``, in this process, in
    ``tmp_path`` (Hydra's own log folder goes to ``tmp_path/hydra``)."""
    monkeypatch.chdir(tmp_path)

    def run(*overrides: str) -> tuple[int, str, str]:
        argv = ["uss-export", *overrides, f"hydra.run.dir={tmp_path / 'hydra'}"]
        monkeypatch.setattr(sys, "argv", argv)
        capsys.readouterr()
        try:
            export_cli.main()
            code = 0
        except SystemExit as exit_info:
            code = int(exit_info.code or 0)
        out, err = capsys.readouterr()
        return code, out, err

    return run
