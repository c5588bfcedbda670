"""Truncated and corrupted ``.vdb`` files: each is refused with one
:class:`~divas_engine.errors.DivasInputError` naming the file, before OpenVDB's reader
(which loops once per counted root entry, even past the end of the stream) sees it.

The cases run in a forked worker under a timeout and a memory limit
(:mod:`tests.fuzz_cases`), so a regression shows as ``hang``/``crash``, not a stuck run."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from divas_engine.io.openvdb_grid import openvdb_module, write_vdb
from divas_engine.scene import DensityGrid

from .fuzz_cases import Family, Worker, check_scene

pytestmark = pytest.mark.skipif(openvdb_module() is None, reason="no OpenVDB module")


def _load(path):
    from divas_engine.io.openvdb_grid import read_vdb

    return read_vdb(path)


@pytest.fixture(scope="module")
def seed(tmp_path_factory):
    """A small valid ``.vdb`` (density and colour) written by the engine."""
    rng = np.random.default_rng(3)
    d = (rng.random((12, 10, 9)) > 0.6) * rng.uniform(0.5, 4.0, (12, 10, 9))
    c = rng.random((12, 10, 9, 3))
    g = DensityGrid(d.astype(np.float32), np.array([[0.0, 0, 0], [1.2, 1.0, 0.9]]), c)
    return write_vdb(tmp_path_factory.mktemp("vdb_seed") / "seed.vdb", g).read_bytes()


@pytest.fixture(scope="module")
def worker():
    w = Worker({"vdb": Family("vdb", [], _load, check=check_scene)}, 1536 << 20)
    yield w
    w.stop()


def _run(worker, tmp_path, data: bytes, name: str = "case.vdb"):
    p = tmp_path / name
    p.write_bytes(data)
    return worker.run("vdb", p, 20.0)


def test_the_seed_reads(worker, seed, tmp_path):
    assert _run(worker, tmp_path, seed) == ("ok", "")


def test_every_truncation_is_one_input_error(worker, seed, tmp_path):
    cuts = sorted(set(range(0, len(seed), max(1, len(seed) // 150))) | set(range(0, 400, 3)))
    for cut in cuts:
        out, detail = _run(worker, tmp_path, seed[:cut], f"cut_{cut}.vdb")
        assert out == "input", (cut, out, detail)
        assert f"cut_{cut}.vdb" in detail, (cut, detail)


def _root_header_offsets(data: bytes) -> list[int]:
    """Where each grid's root node header sits: buffer count 1, a zero background (the
    density's float, the colour's vec3s) and 0 tiles, 1 child (the engine's grids are
    one root child)."""
    out = []
    for bg in (4, 12):
        pat = struct.pack("<i", 1) + bytes(bg) + struct.pack("<II", 0, 1)
        at = data.find(pat)
        assert at > 0
        out.append(at + 4 + bg)
    return out


@pytest.mark.parametrize("grid", [0, 1])
@pytest.mark.parametrize("counts", [(0x7FFFFFFF, 1), (0, 0xFFFFFFFF), (1 << 20, 1), (0, 2)])
def test_corrupted_root_counts_are_refused(worker, seed, tmp_path, grid, counts):
    at = _root_header_offsets(seed)[grid]
    bad = seed[:at] + struct.pack("<II", *counts) + seed[at + 8 :]
    out, detail = _run(worker, tmp_path, bad, "counts.vdb")
    assert out == "input", (out, detail)
    assert "counts.vdb" in detail and "root" in detail


def test_corrupted_header_and_offsets(worker, seed, tmp_path):
    cases = {
        "magic": b"XXXX" + seed[4:],
        "version": seed[:8] + struct.pack("<I", 99) + seed[12:],
        "zeros": bytes(len(seed)),
    }
    # the first grid descriptor's end offset (the third int64 after its three names)
    end_pos = seed.find(b"density") + len(b"density")
    for _ in range(2):  # its type and its instance parent
        n = struct.unpack_from("<I", seed, end_pos)[0]
        end_pos += 4 + n
    cases["offset"] = seed[: end_pos + 16] + struct.pack("<q", 1 << 40) + seed[end_pos + 24 :]
    for name, data in cases.items():
        out, detail = _run(worker, tmp_path, data, f"{name}.vdb")
        assert out == "input", (name, out, detail)
        assert f"{name}.vdb" in detail, (name, detail)
