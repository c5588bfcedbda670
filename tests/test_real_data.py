"""The committed real captures are the unmodified third-party files: SHA-256 as listed in
``tests/data/README.md``, and every folder carries its license. ``tests/data/targets`` is
the team's own ground truth on them (checked by tests/test_real_targets.py)."""

from __future__ import annotations

import hashlib
import re

import pytest

from tests.conftest import REAL_DATA


def _listed() -> dict[str, str]:
    text = (REAL_DATA / "README.md").read_text()
    return dict((m[2], m[1]) for m in re.finditer(r"^([0-9a-f]{64})  (\S+)$", text, re.M))


def test_sha256_list_covers_every_data_file():
    listed = set(_listed())
    on_disk = {
        str(p.relative_to(REAL_DATA))
        for p in REAL_DATA.rglob("*")
        if p.is_file()
        and p.suffix in {".ply", ".spz", ".webp", ".json", ".sog", ".splat"}
        and p.relative_to(REAL_DATA).parts[0] != "targets"
    }
    assert listed == on_disk


@pytest.mark.parametrize("name", sorted(_listed()))
def test_file_is_unmodified(name):
    digest = hashlib.sha256((REAL_DATA / name).read_bytes()).hexdigest()
    assert digest == _listed()[name]


def test_every_folder_has_a_license():
    for folder in {p.parent for p in REAL_DATA.rglob("*.ply")} | {
        p.parent.parent for p in REAL_DATA.rglob("meta.json")
    }:
        names = {p.name for p in folder.iterdir()}
        assert "LICENSE" in names, folder
