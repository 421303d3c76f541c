"""Load a script of ``benchmarks/`` or ``studies/`` as a module, by its file path: the scripts
are not a package (each runs as ``python studies/NAME.py``), so a test that exercises one imports
it this way."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from uss_slam.core.errors import UssSlamError


def load_script(path: Path) -> ModuleType:
    """The script at ``path`` as a module named after its file (``studies/d_probe.py`` ->
    ``d_probe``), executed once per process: later calls return the same module, so every test
    sees (and may monkeypatch) one module object."""
    path = Path(path).resolve()
    name = path.stem
    loaded = sys.modules.get(name)
    if loaded is not None:
        if Path(getattr(loaded, "__file__", "") or "").resolve() != path:
            raise UssSlamError(
                f"{path}: a module named {name!r} is already loaded from "
                f"{getattr(loaded, '__file__', None)}; rename the script"
            )
        return loaded
    if not path.is_file():
        raise UssSlamError(f"{path}: no such script")
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None  # a .py file always has a loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look their module up here
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module
