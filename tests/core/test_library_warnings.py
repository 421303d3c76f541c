"""The libraries' warnings a normal run meets and no user can act on are silenced by name, also
under ``PYTHONWARNINGS=error``; each entry of the list is met through the library's own code."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from types import SimpleNamespace

import pytest

from uss_slam.core.library_warnings import KNOWN, quiet_known_warnings


def _lightnings_pytree() -> None:
    # every training's first batch: Lightning flattens the loaders with a deprecated torch name
    from lightning.pytorch.utilities._pytree import _tree_flatten

    _tree_flatten(object())


def _lightnings_eval_mode_check() -> None:
    # a segmenter whose BatchNorm layers are frozen (model.net.batchnorm=frozen)
    from lightning.pytorch.loops.fit_loop import _FitLoop
    from torch import nn

    loop = SimpleNamespace(trainer=SimpleNamespace(lightning_module=nn.BatchNorm2d(1).eval()))
    _FitLoop._warn_if_modules_in_eval_mode(loop)  # type: ignore[arg-type]


TRIGGERS: dict[str, Callable[[], None]] = {
    "lightning.pytorch.utilities._pytree": _lightnings_pytree,
    "lightning.pytorch.loops.fit_loop": _lightnings_eval_mode_check,
}


@pytest.mark.parametrize("known", KNOWN, ids=lambda k: k.module.replace("\\", ""))
def test_a_known_library_warning_is_quiet_also_under_error(known) -> None:
    trigger = TRIGGERS[known.module.replace("\\", "")]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # PYTHONWARNINGS=error
        with pytest.raises(known.category, match=known.message):
            trigger()  # the library still warns: the entry is needed
        quiet_known_warnings()
        trigger()


def test_another_warning_keeps_the_users_filter() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        quiet_known_warnings()
        with pytest.raises(FutureWarning):
            warnings.warn(
                "`isinstance(treespec, LeafSpec)` is deprecated", FutureWarning, stacklevel=1
            )
