"""The libraries' warnings that a normal run of a console script meets and that no user can act
on, silenced by name (:data:`KNOWN`), so that ``PYTHONWARNINGS=error`` (a developer's setting:
"stop at any warning") stops at the warnings that concern the run, not at these.

Each entry is one warning, matched by its category, the start of its text and the module that
issues it, with the reason it needs no action; any other warning, and the same text from
another module, keeps the filters the user set (``PYTHONWARNINGS``, ``-W``). The scripts'
own code issues no Python warning in a normal run (its warnings are ``<prog>: warning:``
lines).
"""

from __future__ import annotations

import warnings
from typing import NamedTuple


class KnownWarning(NamedTuple):
    """One library warning silenced: ``warnings.filterwarnings("ignore", message, category,
    module)``, and why."""

    category: type[Warning]
    message: str
    module: str
    why: str


KNOWN: tuple[KnownWarning, ...] = (
    KnownWarning(
        FutureWarning,
        r"`isinstance\(treespec, LeafSpec\)` is deprecated",
        r"lightning\.pytorch\.utilities\._pytree",
        "Lightning's own use of a torch name torch deprecated (every training's first batch)",
    ),
    KnownWarning(
        UserWarning,
        r"Found \d+ module\(s\) in eval mode at the start of training",
        r"lightning\.pytorch\.loops\.fit_loop",
        "the segmenter's BatchNorm layers are kept in eval mode on purpose "
        "(model.net.batchnorm=frozen)",
    ),
)


def quiet_known_warnings() -> None:
    """Add an ``ignore`` filter for each of :data:`KNOWN`, in front of the user's filters."""
    for known in KNOWN:
        warnings.filterwarnings("ignore", known.message, known.category, known.module)
