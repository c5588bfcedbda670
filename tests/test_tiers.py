"""The test tiers of ``tests/conftest.py`` follow the tests themselves: a new test module
whose tests take the ``device`` fixture is in the kernels tier without being listed."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

NEW_KERNEL_MODULE = """
def test_on_every_device(device):
    assert device


def test_numpy_side_of_the_same_module():
    pass
"""

NEW_CUDA_MODULE = """
import pytest


@pytest.mark.cuda
def test_only_on_a_gpu():
    pass
"""

ENGINE_MODULE = """
def test_plain():
    pass
"""


def _selected(root: Path, tier: str) -> set[str]:
    p = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider"]
        + ["-m", tier, str(root)],
        cwd=root,
        capture_output=True,
        text=True,
    )
    assert p.returncode in (0, 5), p.stdout + p.stderr  # 5: nothing selected
    return {line.split("::", 1)[1] for line in p.stdout.splitlines() if "::" in line}


def test_kernel_tier_follows_the_device_fixture(tmp_path):
    suite = tmp_path / "tests"
    (suite / "addon").mkdir(parents=True)
    shutil.copy(HERE / "conftest.py", suite / "conftest.py")
    (suite / "test_brand_new_kernel.py").write_text(NEW_KERNEL_MODULE)
    (suite / "test_brand_new_cuda.py").write_text(NEW_CUDA_MODULE)
    (suite / "test_plain.py").write_text(ENGINE_MODULE)
    (suite / "addon" / "test_in_blender.py").write_text(
        ENGINE_MODULE + NEW_KERNEL_MODULE.replace("test_", "test_addon_")
    )
    kernels = _selected(tmp_path, "kernels")
    assert {"test_on_every_device[cpu]", "test_numpy_side_of_the_same_module"} <= kernels
    assert "test_only_on_a_gpu" in kernels
    assert _selected(tmp_path, "engine") == {"test_plain"}
    addon = _selected(tmp_path, "addon")
    assert "test_plain" in addon and "test_addon_on_every_device[cpu]" in addon
    assert not kernels & (addon | {"test_plain"})
