"""The extension package: manifest contents, the build script's manifest rewrite and zip
layout, the locked versions of its wheels and the Blender releases of each Python
(the real build, installed into Blender: ``test_extension_install.py``).
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
ADDON = REPO / "blender_addon"
SCRIPT = REPO / "blender_scripts" / "build_extension.py"


def build_module():
    spec = importlib.util.spec_from_file_location("build_extension", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def validate(path: Path) -> subprocess.CompletedProcess:
    packager = build_module()._packager()
    if packager is None:
        pytest.skip("no Blender extension packager (blender binary or bpy module)")
    return subprocess.run(packager + ["validate", str(path)], capture_output=True, text=True)


def check_manifest(m: dict, blender_min: str = "4.2.0") -> None:
    assert m["schema_version"] == "1.0.0"
    assert m["id"] == "divas" and m["type"] == "add-on"
    assert m["blender_version_min"] == blender_min
    assert m["license"] == ["SPDX:GPL-3.0-or-later"]
    assert re.fullmatch(r"\d+\.\d+\.\d+", m["version"])
    assert m["permissions"], "permissions with reasons"
    for key, reason in m["permissions"].items():
        assert key in {"files", "network", "clipboard", "camera", "microphone"}
        assert isinstance(reason, str) and 0 < len(reason) <= 64 and not reason.endswith(".")


def test_source_manifest():
    m = tomllib.loads((ADDON / "blender_manifest.toml").read_text())
    check_manifest(m)
    assert "wheels" not in m and "platforms" not in m  # written per build
    res = validate(ADDON)
    assert res.returncode == 0, res.stdout + res.stderr


def test_addon_uses_relative_imports_only():
    for py in ADDON.rglob("*.py"):
        text = py.read_text()
        assert not re.search(r"(?m)^\s*(from|import)\s+blender_addon\b", text), py


def _fake_wheels(tmp: Path) -> list[str]:
    names = [
        "divas-0.1.0-py3-none-any.whl",
        "tqdm-4.70.1-py3-none-any.whl",
        "scipy-1.17.1-cp311-cp311-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl",
        "scipy-1.17.1-cp313-cp313-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl",
        "scipy-1.17.1-cp311-cp311-win_amd64.whl",
    ]
    for n in names:
        with zipfile.ZipFile(tmp / n, "w") as z:
            z.writestr("placeholder.txt", n)
    return names


def test_manifest_of_each_python_names_its_blender_versions(tmp_path):
    mod = build_module()
    for py, (lo, hi) in mod.BLENDER_RANGE.items():
        dst = tmp_path / f"m{py}.toml"
        mod.write_manifest(
            ADDON / "blender_manifest.toml", dst, ["./wheels/x.whl"], ["linux-x64"], (lo, hi)
        )
        m = tomllib.loads(dst.read_text())
        assert m["blender_version_min"] == lo and m.get("blender_version_max") == hi
        assert m["wheels"] == ["./wheels/x.whl"] and m["permissions"]
    for py in mod.PYTHONS:
        pins = mod.pinned(py)
        assert "tqdm" not in pins and "numpy" not in pins and set(mod.SAM_ONLY) <= set(pins)
        assert {"warp-lang", "scipy", "plyfile"} <= set(pins)


def test_bundled_wheels_are_the_locked_versions():
    """The extension's wheels are the versions the lock of each Python pins (the ones the
    tests passed with), read from the lock file itself."""
    mod = build_module()
    for py, lock in mod.LOCKS.items():
        lines = [ln for ln in lock.read_text().splitlines() if ln and not ln.startswith("#")]
        locked = dict(ln.split("==") for ln in lines)
        for name, version in mod.pinned(py).items():
            assert locked[name] == version, (py, name)


def test_manifest_rewrite_and_fallback_zip(tmp_path):
    """Without downloading: the staged manifest lists the wheels; the fallback zip keeps
    only one platform's wheels and Blender's validator accepts it."""
    mod = build_module()
    stage = tmp_path / "stage" / "divas"
    shutil.copytree(ADDON, stage, ignore=shutil.ignore_patterns("__pycache__"))
    (stage / "wheels").mkdir()
    names = _fake_wheels(stage / "wheels")
    mod.write_manifest(
        ADDON / "blender_manifest.toml",
        stage / "blender_manifest.toml",
        [f"./wheels/{n}" for n in names],
        ["linux-x64", "windows-x64"],
    )
    m = tomllib.loads((stage / "blender_manifest.toml").read_text())
    check_manifest(m)
    assert m["wheels"] == [f"./wheels/{n}" for n in names]
    assert m["platforms"] == ["linux-x64", "windows-x64"]
    out = tmp_path / "dist"
    out.mkdir()
    zips = mod._zip_ourselves(stage, out, "0.1.0", ["linux-x64", "windows-x64"])
    assert [z.name for z in zips] == ["divas-0.1.0-linux_x64.zip", "divas-0.1.0-windows_x64.zip"]
    with zipfile.ZipFile(zips[0]) as z:
        listed = tomllib.loads(z.read("blender_manifest.toml").decode())
        files = set(z.namelist())
    assert listed["platforms"] == ["linux-x64"]
    assert "win_amd64" not in " ".join(listed["wheels"])
    assert {w[2:] for w in listed["wheels"]} <= files
    assert "__init__.py" in files and "operators/import_splats.py" in files
    res = validate(zips[0])
    assert res.returncode == 0, res.stdout + res.stderr


def test_each_python_serves_the_blender_releases_that_run_it():
    """The zip of the running Python names a Blender range that holds this release, the
    other Python's does not (a Blender only loads the wheels of its own Python)."""
    import bpy

    ranges = build_module().BLENDER_RANGE
    this = f"{sys.version_info.major}{sys.version_info.minor}"
    version = bpy.app.version

    def holds(lo, hi) -> bool:
        inside = tuple(map(int, lo.split("."))) <= version
        return inside and (hi is None or version < tuple(map(int, hi.split("."))))

    assert holds(*ranges[this]), (this, version)
    assert not any(holds(*r) for py, r in ranges.items() if py != this)
