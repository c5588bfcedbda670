"""Shared test fixtures: the real third-party captures committed in ``tests/data``.

``tests/data/README.md`` gives each file's source, license and SHA-256; the repository
needs nothing beside it to run its tests.
"""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO / "tests" / "data"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """Folder of the real captures (``tests/data``)."""
    if not REAL_DATA.is_dir():
        pytest.fail(f"test data not found at {REAL_DATA}: the checkout is incomplete")
    return REAL_DATA
