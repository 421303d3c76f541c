"""Fixtures of the research scripts' tests."""

from __future__ import annotations

from types import ModuleType

import pytest
from shared_helpers import study


@pytest.fixture(scope="module")
def fresh() -> ModuleType:
    """``studies/fresh_cases.py``: the held-out sets' runner, its case format and verdicts."""
    return study("fresh_cases")
