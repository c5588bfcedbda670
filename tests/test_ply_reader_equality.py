"""The faster Gaussian-PLY reader (one gather per output from
a float32 view of each chunk, SH straight into its rows, 3DGS flattening on entry
arrays) gives bit-identical scenes to the reader it replaced.

The reference below is that reader's conversion, written out plainly: one property at a
time (``astype``), the SH filled coefficient by coefficient, and the 3DGS flattening
through ``quat_to_rotmat`` → columns → ``np.cross`` → ``rotmat_to_quat`` on ``[N,3,3]``
matrices (the geometry helpers, unchanged).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plyfile
import pytest

from divas_engine.geometry import (
    normalize_quats,
    quat_rotation_entries,
    quat_to_rotmat,
    rotation_entries_to_quat,
    rotmat_to_quat,
)
from divas_engine.io import ply
from divas_engine.io.gaussians import sigmoid
from divas_engine.scene import sh_coeff_count

DATA = Path(__file__).parent / "data" / "gaussiansplats3d-lod"


def _reference_flatten(q: np.ndarray, s3: np.ndarray):
    r = quat_to_rotmat(q.astype(np.float32))
    order = np.argsort(-s3, axis=1, kind="stable")
    a, b = order[:, 0], order[:, 1]
    idx = np.arange(len(q))
    tu, tv = r[idx, :, a], r[idx, :, b]
    r2 = np.stack([tu, tv, np.cross(tu, tv)], axis=2)
    q2 = rotmat_to_quat(r2).astype(np.float32)
    return q2, np.stack([s3[idx, a], s3[idx, b]], axis=1).astype(np.float32)


def _reference_read(path: Path) -> dict[str, np.ndarray]:
    """The replaced reader's arithmetic on the whole file at once (plyfile body)."""
    rows = plyfile.PlyData.read(str(path))["vertex"].data
    names = rows.dtype.names
    n_rest = sum(nm.startswith("f_rest_") for nm in names)
    k = next(sh_coeff_count(d) for d in range(4) if n_rest == 3 * (sh_coeff_count(d) - 1))
    n_scale = 3 if "scale_2" in names else 2

    def col(nm: str) -> np.ndarray:
        return rows[nm].astype(np.float32, copy=False)

    m = np.stack([col("x"), col("y"), col("z")], 1)
    q = np.stack([col(f"rot_{i}") for i in range(4)], 1)
    s = np.stack([col(f"scale_{i}") for i in range(n_scale)], 1)
    o = col("opacity")
    c = np.empty((len(rows), k, 3), np.float32)
    for ch in range(3):
        c[:, 0, ch] = col(f"f_dc_{ch}")
        for j in range(k - 1):
            c[:, j + 1, ch] = col(f"f_rest_{ch * (k - 1) + j}")
    ok = (
        np.isfinite(m).all(1)
        & np.isfinite(q).all(1)
        & np.isfinite(s).all(1)
        & np.isfinite(o)
        & np.isfinite(c).all((1, 2))
    )
    with np.errstate(over="ignore", invalid="ignore"):
        s_act = np.exp(np.clip(s, -80.0, 80.0)).astype(np.float32)
    ok &= np.linalg.norm(q, axis=1) > 0
    s_act = np.where(ok[:, None], s_act, np.float32(1.0))
    qn = normalize_quats(np.where(ok[:, None], q, 1.0))
    if n_scale == 3:
        q2, s2 = _reference_flatten(qn, s_act)
    else:
        q2, s2 = qn, np.ascontiguousarray(s_act, dtype=np.float32)
    keep = np.flatnonzero(ok)
    out = {"means": m, "quats": q2, "scales": s2, "opacities": sigmoid(o), "sh": c}
    out = {key: v[keep] for key, v in out.items()}
    out["kept"] = keep
    out["scale_n"] = s_act.min(1)[keep] if n_scale == 3 else None
    return out


def _assert_same(path: Path) -> None:
    ref = _reference_read(path)
    got = ply.read_gaussian_ply(path)
    for key in ("means", "quats", "scales", "opacities", "sh"):
        a, b = getattr(got, key), ref[key]
        assert a.dtype == b.dtype and a.shape == b.shape, key
        # bit-identical: compare the bytes (NaN-free after the finite filter)
        assert a.tobytes() == np.ascontiguousarray(b).tobytes(), key
    np.testing.assert_array_equal(got.source.kept_rows, ref["kept"])
    if ref["scale_n"] is None:
        assert got.scale_n is None
    else:
        assert got.scale_n.tobytes() == ref["scale_n"].tobytes()


@pytest.mark.parametrize("name", ["lod1_tile_0_0.5x", "lod2_tile_0", "lod3_tile_0"])
def test_committed_plys_read_bit_identically(name):
    _assert_same(DATA / f"{name}.ply")


def _write(path: Path, n: int, degree: int, scale_axes: int, dtype: str, seed: int) -> None:
    k1 = sh_coeff_count(degree) - 1
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * k1)]
    names += ["opacity"] + [f"scale_{i}" for i in range(scale_axes)]
    names += [f"rot_{i}" for i in range(4)]
    rng = np.random.default_rng(seed)
    rows = np.zeros(n, [(nm, dtype) for nm in names])
    for nm in names:
        rows[nm] = rng.normal(size=n)
    for i in range(scale_axes):
        rows[f"scale_{i}"] = rng.uniform(-6, -3, n)
    rows["scale_1"][:50] = rows["scale_0"][:50]  # ties: the stable order decides
    rows["x"][7], rows["f_rest_3" if k1 else "f_dc_1"][11] = np.nan, np.inf  # dropped
    rows["nx"][13] = np.nan  # an unused property: kept
    for i in range(4):
        rows[f"rot_{i}"][17] = 0.0  # a zero quaternion: dropped
    # every branch of Shepperd's method: identity-like, and 180° about x, y and z
    for r, (w, x, y, z) in zip(
        range(20, 24), [(1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1)]
    ):
        rows["rot_0"][r], rows["rot_1"][r], rows["rot_2"][r], rows["rot_3"][r] = w, x, y, z
    ply.write_ply_rows(path, {"vertex": rows})


@pytest.mark.parametrize(
    "degree,axes,dtype",
    [(3, 3, "<f4"), (3, 2, "<f4"), (1, 3, "<f4"), (0, 2, "<f4"), (3, 3, ">f4"), (2, 3, "<f8")],
)
def test_synthetic_plys_read_bit_identically(tmp_path, monkeypatch, degree, axes, dtype):
    """SH degrees 0–3, 2DGS and 3DGS, NaN/Inf and zero-quaternion rows, ties in the
    scales; float32 (the fast path) and big-endian / float64 files (per property);
    chunk boundaries crossed (a small CHUNK_ROWS, a ragged last chunk)."""
    path = tmp_path / "scene.ply"
    _write(path, 5000, degree, axes, dtype, seed=degree * 10 + axes)
    _assert_same(path)
    monkeypatch.setattr(ply, "CHUNK_ROWS", 1536)
    _assert_same(path)


def test_rotation_entries_match_the_matrix_helpers():
    rng = np.random.default_rng(3)
    q = normalize_quats(rng.normal(size=(20000, 4)).astype(np.float32))
    q[:4] = np.eye(4, dtype=np.float32)  # w, x, y, z axes: each branch of Shepperd's method
    ent = quat_rotation_entries(q)
    r = quat_to_rotmat(q)
    for i in range(3):
        for j in range(3):
            assert ent[i][j].tobytes() == np.ascontiguousarray(r[:, i, j]).tobytes()
    branches = np.argmax(
        np.stack([np.trace(r, axis1=1, axis2=2), *(r[:, d, d] for d in range(3))]), 0
    )
    assert set(branches.tolist()) == {0, 1, 2, 3}
    assert rotation_entries_to_quat(ent).tobytes() == rotmat_to_quat(r).tobytes()


def test_reused_chunks_only_when_asked(tmp_path):
    """Other readers keep every chunk (``iter_vertex_chunks`` default): no shared buffer."""
    path = tmp_path / "scene.ply"
    _write(path, 3000, 1, 2, "<f4", seed=5)
    layout = ply.read_ply_header(path)
    chunks = [c for _, c in ply.iter_vertex_chunks(layout, 1000)]
    whole = plyfile.PlyData.read(str(path))["vertex"].data
    np.testing.assert_array_equal(np.concatenate(chunks)["x"], whole["x"])
