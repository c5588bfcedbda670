"""instant-ngp snapshots: layout, frames, round trips, masking and refusals.

The conventions are checked against an independent public reader of the same density
grids, torch-ngp (``ashawkey/torch-ngp``, ``raymarching/src/raymarching.cu``):
``__morton3D`` puts ``x`` in bit 0 (l. 56-71), and a point ``x ∈ [−b, b]`` of cascade
``c`` (``b = 2^c``) is in cell ``floor(0.5·(x/b + 1)·H)`` (l. 368-378). instant-ngp's cube
``[0, 1]`` is torch-ngp's ``[−1, 1]`` halved and shifted, so the same cell must come out.
"""

from __future__ import annotations

import gzip

import msgpack
import numpy as np
import pytest

from divas_engine import load_scene
from divas_engine.errors import DivasInputError
from divas_engine.export import export_selection
from divas_engine.io.instant_ngp import (
    STEPSIZE,
    NgpFrame,
    read_ngp_document,
    write_ngp_document,
)
from divas_engine.io.instant_ngp_writer import snapshot_document
from divas_engine.io.limits import load_limits
from divas_engine.io.load import detect_format
from divas_engine.io.ngp_cascades import morton3d, morton3d_invert

from .ngp_cases import look_at_camera, small_config, sphere_snapshot
from .ngp_reference import random_network

R = 128


def _torch_ngp_morton(x: int, y: int, z: int) -> int:
    """Bit by bit: bit 3k of the code is bit k of x, 3k+1 of y, 3k+2 of z."""
    code = 0
    for k in range(10):
        code |= ((x >> k) & 1) << (3 * k)
        code |= ((y >> k) & 1) << (3 * k + 1)
        code |= ((z >> k) & 1) << (3 * k + 2)
    return code


def _torch_ngp_cell(ngp: np.ndarray, cascade: int) -> np.ndarray:
    x = 2.0 * (np.asarray(ngp, float) - 0.5)  # torch-ngp's frame: the cube is [−1, 1]
    b = 2.0**cascade
    return np.floor(0.5 * (x / b + 1) * R).astype(int)


def test_morton_order_matches_torch_ngp_bit_order():
    rng = np.random.default_rng(0)
    xyz = rng.integers(0, R, (500, 3))
    codes = morton3d(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    assert [int(c) for c in codes] == [_torch_ngp_morton(*map(int, p)) for p in xyz]
    back = np.stack(morton3d_invert(codes), 1)
    assert np.array_equal(back, xyz)


def _write(tmp_path, doc, name="s.ingp", compressed=True):
    p = tmp_path / name
    write_ngp_document(p, doc, compressed)
    return p


def test_grid_round_trips_bit_exactly(tmp_path):
    doc, frame = sphere_snapshot()
    raw = doc["snapshot"]["density_grid_binary"]
    for name, comp in (("a.ingp", True), ("a.msgpack", False)):
        p = _write(tmp_path, doc, name, comp)
        back, was_comp = read_ngp_document(p)
        assert was_comp == comp
        assert back["snapshot"]["density_grid_binary"] == raw
        # through the lattice: every occupied cell's float16 comes back from σ
        g = load_scene(p)
        assert g.source.format == ("ingp" if comp else "msgpack")
        cells = np.frombuffer(raw, "<f2")
        occ = np.nonzero(cells > 0.01)[0]
        x, y, z = morton3d_invert(occ)
        ngp = (np.stack([x, y, z], 1) + 0.5) / R
        w = frame.to_world(ngp)
        ijk = np.floor((w - g.aabb[0]) / g.voxel_size).astype(int)
        sig = g.density[ijk[:, 2], ijk[:, 1], ijk[:, 0]]
        again = (sig / np.float32(frame.scale) * np.float32(STEPSIZE)).astype(np.float16)
        assert np.array_equal(again.view(np.uint16), cells[occ].view(np.uint16))
        # nothing the grid does not hold: unseen (−1) and empty cells are 0
        assert int((g.density > 0).sum()) == len(occ)


@pytest.mark.parametrize("axes_mitsuba", [False, True])
def test_known_point_lands_in_its_cell_of_every_cascade(tmp_path, axes_mitsuba):
    frame = NgpFrame(0.21, (0.45, 0.55, 0.52), axes_mitsuba)
    aabb_scale = 4  # 3 cascades: 0.5 ± 0.5, ± 1, ± 2
    C = 3
    # world points each inside cascade m but outside cascade m − 1
    pts_ngp = np.array([[0.61, 0.37, 0.52], [1.31, 0.05, 0.93], [2.2, -0.9, 0.4]])
    pts = frame.to_world(pts_ngp)
    ot = np.zeros((C, R, R, R), np.float32)
    for m, q in enumerate(pts_ngp):
        cell = _torch_ngp_cell(q, m)
        assert np.all((cell >= 0) & (cell < R))
        ot[m, cell[0], cell[1], cell[2]] = 0.25 * (m + 1)
    doc = snapshot_document(ot, frame, aabb_scale)
    cells = np.frombuffer(doc["snapshot"]["density_grid_binary"], "<f2").reshape(C, -1)
    for m, q in enumerate(pts_ngp):
        code = _torch_ngp_morton(*map(int, _torch_ngp_cell(q, m)))
        assert cells[m, code] == np.float16(0.25 * (m + 1))
    g = load_scene(_write(tmp_path, doc))
    for m, p in enumerate(pts):
        ijk = np.floor((p - g.aabb[0]) / g.voxel_size).astype(int)
        want = 0.25 * (m + 1) / STEPSIZE * frame.scale
        assert g.density[ijk[2], ijk[1], ijk[0]] == pytest.approx(want, rel=1e-3), m
    # the lattice keeps each cascade's own cell size: the cascade-2 cell spans 4³ cells
    assert g.density[g.density > 0].size == 1 + 2**3 + 4**3


def test_axis_cycle_and_cameras_follow_nerf_loader(tmp_path):
    frame = NgpFrame(0.4, (0.5, 0.45, 0.55))
    target = np.array([0.3, -0.2, 0.1])
    cam = look_at_camera([2.0, 0.5, 0.8], target, name="train_000")
    doc, _ = sphere_snapshot(centre_world=target, radius_world=0.2, frame=frame, cameras=[cam])
    # instant-ngp's own view: the xform is in the NeRF frame, rows cycled (y, z, x)
    M = np.asarray(doc["snapshot"]["nerf"]["dataset"]["xforms"][0]["start"])
    t = frame.to_ngp(target)
    uvz = M[:, :3].T @ (t - M[:, 3])
    uv_ngp = uvz[:2] / uvz[2] * cam.fx + np.array([cam.cx, cam.cy])
    g = load_scene(_write(tmp_path, doc))
    (back,) = g.extras["cameras"]
    assert back.name == "train_000"
    assert np.allclose(back.c2w, cam.c2w, atol=1e-6)
    uv, _ = back.project(target[None])
    assert np.allclose(uv[0], uv_ngp, atol=1e-6)
    # the ball is where the camera sees it
    idx = np.argwhere(g.density > 0)[:, ::-1]
    centroid = (g.aabb[0] + (idx + 0.5) * g.voxel_size).mean(0)
    assert np.allclose(centroid, target, atol=g.voxel_size.max())


def test_format_detection(tmp_path):
    doc, _ = sphere_snapshot(unseen_corner=False)
    a = _write(tmp_path, doc, "x.ingp")
    b = _write(tmp_path, doc, "x.msgpack", compressed=False)
    assert detect_format(a) == "ingp" and detect_format(b) == "msgpack"
    renamed = tmp_path / "misnamed.bin"
    renamed.write_bytes(a.read_bytes())
    assert detect_format(renamed) == "ingp"


def test_network_is_read_and_counted(tmp_path):
    cfg = small_config()
    net, params = random_network(cfg, 1, seed=3)
    doc, _ = sphere_snapshot(network=net, config=cfg)
    g = load_scene(_write(tmp_path, doc))
    assert g.network is not None and g.extras["network_note"] == ""
    assert np.array_equal(g.network.network.table, net.table)
    # a parameter count that does not match the config: the grid loads, the network not
    doc["snapshot"]["params_binary"] = doc["snapshot"]["params_binary"][:-2]
    g = load_scene(_write(tmp_path, doc, "cut.ingp"))
    assert g.network is None and "parameters" in g.extras["network_note"]


def test_masked_export_zeroes_everything_outside_the_object(tmp_path):
    doc, frame = sphere_snapshot(radius_world=0.4)
    src = _write(tmp_path, doc)
    g = load_scene(src)
    idx = np.argwhere(g.density > 0)
    sel = np.zeros(g.density.shape, bool)
    half = idx[idx[:, 2] < np.median(idx[:, 2])]  # the low-x half of the ball
    sel[tuple(half.T)] = True
    out = tmp_path / "sel.ingp"
    res = export_selection(g, sel, out, vdb_path=None)
    assert res.format == "ingp"
    m = load_scene(out)
    # the masked snapshot holds exactly the selected voxels (one cascade: cells are voxels)
    mi = np.argwhere(m.density > 0)[:, ::-1]
    w = m.aabb[0] + (mi + 0.5) * m.voxel_size
    gi = np.floor((w - g.aabb[0]) / g.voxel_size).astype(int)
    assert np.all(sel[gi[:, 2], gi[:, 1], gi[:, 0]])
    assert len(mi) == int((sel & (g.density > 0)).sum())
    assert np.allclose(m.density[m.density > 0], g.density[gi[:, 2], gi[:, 1], gi[:, 0]])
    orig = np.frombuffer(doc["snapshot"]["density_grid_binary"], "<f2")
    new = np.frombuffer(read_ngp_document(out)[0]["snapshot"]["density_grid_binary"], "<f2")
    changed = orig != new
    assert np.all(new[changed] == 0) and np.all(orig[changed] > 0)
    assert 0 < changed.sum() < (orig > 0).sum()
    # every voxel selected: the grid comes back bit for bit
    full = tmp_path / "all.ingp"
    export_selection(g, np.ones_like(sel), full)
    assert read_ngp_document(full)[0]["snapshot"]["density_grid_binary"] == orig.tobytes()
    # the rest of the document is untouched
    a, b = read_ngp_document(src)[0], read_ngp_document(out)[0]
    a["snapshot"].pop("density_grid_binary")
    b["snapshot"].pop("density_grid_binary")
    assert a == b


def test_refusals(tmp_path):
    doc, _ = sphere_snapshot()
    good = _write(tmp_path, doc)
    data = good.read_bytes()
    cut = tmp_path / "cut.ingp"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(DivasInputError, match="truncated|malformed|cannot read"):
        load_scene(cut)
    bad = dict(doc)
    bad["snapshot"] = dict(doc["snapshot"])
    bad["snapshot"]["density_grid_binary"] = doc["snapshot"]["density_grid_binary"][:-2]
    with pytest.raises(DivasInputError, match="cells"):
        load_scene(_write(tmp_path, bad, "short.ingp"))
    cfg_only = _write(tmp_path, {"encoding": {"otype": "HashGrid"}}, "cfg.ingp")
    with pytest.raises(DivasInputError, match="snapshot"):
        load_scene(cfg_only)
    small = load_limits(min_inflate_bytes=1 << 20, max_inflate_ratio=2)
    with small, pytest.raises(DivasInputError, match="limit"):
        load_scene(good)
    odd = tmp_path / "odd.ingp"
    odd.write_bytes(gzip.compress(msgpack.packb([1, 2, 3])))
    with pytest.raises(DivasInputError):
        load_scene(odd)
