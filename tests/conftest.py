"""Shared test fixtures: the real third-party captures committed in ``tests/data``.

``tests/data/README.md`` gives each file's source, license and SHA-256; the repository
needs nothing beside it to run its tests.
"""

from __future__ import annotations

import os
import sys
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


def _devices() -> list:
    """Every Warp device the kernel tests run on: the CPU always, CUDA when present
    (those cases carry the ``cuda`` marker)."""
    import warp as wp

    devs: list = ["cpu"]
    if wp.get_cuda_device_count() > 0:
        devs.append(pytest.param("cuda:0", marks=pytest.mark.cuda))
    return devs


@pytest.fixture(scope="session", params=_devices())
def device(request) -> str:
    """The Warp device of a kernel test, parametrised over :func:`_devices`."""
    return request.param


# Test tiers (``make test-engine`` etc.): the add-on tests (folder ``addon``) need the
# ``bpy`` module; a kernel test module is one with a test that takes the ``device``
# fixture or carries the ``cuda`` marker (Warp kernels against NumPy references, on every
# available device): all its tests are in the kernels tier; every other test is an
# engine test.
def _is_kernel_test(item) -> bool:
    return "device" in getattr(item, "fixturenames", ()) or item.get_closest_marker("cuda")


def pytest_collection_modifyitems(config, items) -> None:
    kernel_modules = {Path(str(i.fspath)) for i in items if _is_kernel_test(i)}
    for item in items:
        path = Path(str(item.fspath))
        if "addon" in path.parts:
            item.add_marker(pytest.mark.addon)
        elif path in kernel_modules:
            item.add_marker(pytest.mark.kernels)
        else:
            item.add_marker(pytest.mark.engine)


# Ending the process as soon as the result is out (DIVAS_TEST_HARD_EXIT=1, set by the
# Makefile's add-on release matrix): the bpy 4.5 module can deadlock in Blender's own
# shutdown at interpreter exit (gdb: every thread waits on a futex, Blender's GPU workers
# among them), after pytest has printed its summary, so a CI run would hang until its
# time limit. ``os._exit`` skips the interpreter's (and Blender's) exit
# handlers; pytest has written everything by the last ``pytest_unconfigure``.
_EXIT_STATUS = "divas_exit_status"


def pytest_sessionfinish(session, exitstatus) -> None:
    setattr(session.config, _EXIT_STATUS, int(exitstatus))


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config) -> None:
    if os.environ.get("DIVAS_TEST_HARD_EXIT") != "1" or not hasattr(config, _EXIT_STATUS):
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(getattr(config, _EXIT_STATUS))
