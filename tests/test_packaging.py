"""The installed distribution: the engine and its kernels under the project's own names.

A generic top-level ``kernels`` package would land in the site-packages that every
Blender extension shares; the repository's ``kernels/`` folder ships as ``divas_kernels``.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _source_packages() -> set[str]:
    pkgs = {
        ".".join(p.parent.relative_to(REPO).parts)
        for p in (REPO / "divas_engine").rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    return pkgs | {"divas_kernels"}


def test_every_source_package_is_listed():
    listed = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    assert set(listed) == _source_packages()


def test_wheel_ships_namespaced_kernels(tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(REPO)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    (wheel,) = tmp_path.glob("divas-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"divas_engine", "divas_kernels"}
    assert "divas_kernels/rasterize.py" in names and "divas_kernels/__init__.py" in names
    kernel_files = {p.name for p in (REPO / "kernels").glob("*.py")}
    assert kernel_files <= {n.split("/")[1] for n in names if n.startswith("divas_kernels/")}
