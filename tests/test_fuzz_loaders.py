"""A seeded fuzz run per loader family in CI — mutated copies of small
valid files (bit flips, truncation, header edits, numeric extremes, JSON structure
edits) either load sanely or raise DivasInputError; nothing crashes, hangs (20 s per
case) or blows the memory limit (1.5 GiB above the child's size). The big run is
``benchmarks/fuzz_loaders.py`` (≥ 30,000 cases)."""

from __future__ import annotations

import os

import pytest

from .fuzz_cases import FAMILIES, build_seeds, run_case, run_family

#: cases per family (session cases replay a session: fewer); DIVAS_FUZZ_CASES overrides
CASES = int(os.environ.get("DIVAS_FUZZ_CASES", "250"))


@pytest.fixture(scope="module")
def families(tmp_path_factory):
    return build_seeds(tmp_path_factory.mktemp("fuzz_seeds"))


@pytest.mark.parametrize("name", FAMILIES)
def test_seeds_are_valid(families, name):
    """The unmutated seeds load cleanly (so the fuzz starts from real files)."""
    if name not in families:
        pytest.skip(f"{name}: no module to write its seed (OpenVDB)")
    fam = families[name]
    for s in fam.seeds:
        out, detail = run_case(fam.load, fam.check, s, 60, 1536 << 20, fam.fork)
        assert out == "ok", (s, out, detail)


@pytest.mark.parametrize("name", FAMILIES)
def test_fuzz_loads_or_refuses(families, name, tmp_path):
    if name not in families:
        pytest.skip(f"{name}: no module to write its seed (OpenVDB)")
    fam = families[name]
    n = CASES // 3 if name == "session" else CASES
    res = run_family(fam, n, seed=14, work=tmp_path)
    bad = {o: res[o][:5] for o in ("garbage", "crash", "hang", "memory") if res[o]}
    assert not bad, f"{name}: {bad}"
    assert len(res["ok"]) + len(res["input"]) == n
    assert res["input"], "no case was refused: the mutations do not reach the loader"


def _sleep(path):
    import time

    time.sleep(30)


def _hog(path):
    import numpy as np

    return np.ones(8 << 30, np.uint8)  # 8 GiB, over the limit


def _boom(path):
    raise KeyError("boom")


@pytest.mark.parametrize("load, outcome", [(_sleep, "hang"), (_hog, "memory"), (_boom, "crash")])
def test_harness_catches_hangs_blowups_and_crashes(tmp_path, load, outcome):
    """The guards themselves: a hang is killed, an allocation past the limit fails."""
    p = tmp_path / "x"
    p.write_bytes(b"x")
    out, _ = run_case(load, None, p, timeout=2.0, mem_bytes=512 << 20)
    assert out == outcome
