"""OpenVDB and torch-ngp density grids, the shading of colourless grids, and the command
line on instant-ngp snapshots."""

from __future__ import annotations

import json

import numpy as np
import pytest

from divas_engine import load_scene
from divas_engine.errors import DivasInputError
from divas_engine.export import export_selection
from divas_engine.io import openvdb_grid
from divas_engine.io.instant_ngp import write_ngp_document
from divas_engine.io.openvdb_grid import openvdb_module, read_vdb, write_vdb
from divas_engine.render import RenderConfig, make_renderer
from divas_engine.render.grid_shading import shaded_rgb
from divas_engine.scene import DensityGrid

from .ngp_cases import look_at_camera, sphere_snapshot

needs_vdb = pytest.mark.skipif(openvdb_module() is None, reason="no OpenVDB module")


def _grid(seed=0, rgb=True):
    rng = np.random.default_rng(seed)
    d = (rng.random((5, 6, 7)) > 0.5).astype(np.float32) * rng.uniform(1, 9, (5, 6, 7))
    d = d.astype(np.float32)
    c = rng.random((5, 6, 7, 3)).astype(np.float32) if rgb else None
    return DensityGrid(d, np.array([[0.0, 1, 2], [0.7, 1.6, 2.5]]), c)


@needs_vdb
def test_vdb_round_trip(tmp_path):
    g = _grid()
    p = write_vdb(tmp_path / "g.vdb", g)
    h = load_scene(p)
    assert h.source.format == "vdb"
    # the active box may be smaller than the grid's: compare on world positions
    idx = np.argwhere(h.density > 0)[:, ::-1]
    w = h.aabb[0] + (idx + 0.5) * h.voxel_size
    gi = np.floor((w - g.aabb[0]) / g.voxel_size + 1e-9).astype(int)
    assert np.allclose(h.voxel_size, g.voxel_size)
    assert np.array_equal(h.density[tuple(idx[:, ::-1].T)], g.density[gi[:, 2], gi[:, 1], gi[:, 0]])
    assert int((h.density > 0).sum()) == int((g.density > 0).sum())
    assert np.allclose(h.rgb[tuple(idx[:, ::-1].T)], g.rgb[gi[:, 2], gi[:, 1], gi[:, 0]])


def _render(grid, cam):
    r = make_renderer(grid, device="cpu").render(cam)
    return np.asarray(r.alpha), np.asarray(r.rgb)


@needs_vdb
def test_vdb_round_trip_keeps_the_lattice_and_the_views(tmp_path):
    """The engine's own ``.vdb`` reads back on the lattice it wrote, occupied voxels
    touching its faces included, and renders the same views."""
    g = _grid(seed=4)
    g.density[:, :, 0] = 2.0  # occupied on the lattice's face: no margin there
    g.density[0, 0, 0] = 0.0  # the active box is smaller than the lattice elsewhere
    h = read_vdb(write_vdb(tmp_path / "g.vdb", g))
    np.testing.assert_allclose(h.aabb, g.aabb, atol=1e-12)
    assert np.array_equal(h.density, g.density)
    assert np.array_equal(h.rgb, np.where((g.density > 0)[..., None], g.rgb, 0))
    cam = look_at_camera(g.aabb.mean(0) + [1.5, 0.9, 1.2], g.aabb.mean(0))
    a0, _ = _render(g, cam)
    a1, _ = _render(h, cam)
    assert a0.max() > 0.5 and np.array_equal(a0, a1)


@needs_vdb
def test_foreign_vdb_lattice_holds_the_trilinear_support(tmp_path):
    """A ``.vdb`` written by another tool: each voxel lands at its transform's world
    centre, and the lattice is the active box and one background cell around it, so it
    renders as the same grid with that empty margin (the field's whole support)."""
    vdb = openvdb_module()
    vox, origin = 0.1, np.array([0.3, -0.2, 1.0])
    ijk = np.array([[5, 7, -3], [6, 7, -3], [5, 9, -1], [8, 8, -2]])
    vals = np.array([1.5, 3.0, 6.0, 9.0], np.float32)
    grid = vdb.FloatGrid()
    acc = grid.getAccessor()
    for (i, j, k), v in zip(ijk, vals):
        acc.setValueOn((int(i), int(j), int(k)), float(v))
    grid.name = "density"
    grid.transform = vdb.createLinearTransform(
        [[vox, 0, 0, 0], [0, vox, 0, 0], [0, 0, vox, 0], [*origin.tolist(), 1]]
    )
    vdb.write(str(tmp_path / "f.vdb"), grids=[grid])
    h = read_vdb(tmp_path / "f.vdb")
    lo, hi = ijk.min(0) - 1, ijk.max(0) + 1
    assert h.density.shape == tuple((hi - lo + 1)[::-1])
    np.testing.assert_allclose(h.aabb[0], origin + (lo - 0.5) * vox, atol=1e-9)
    world = origin + ijk * vox  # voxel centres (indexToWorld)
    cell = np.floor((world - h.aabb[0]) / h.voxel_size).astype(int)
    assert np.array_equal(h.density[cell[:, 2], cell[:, 1], cell[:, 0]], vals)
    assert int((h.density > 0).sum()) == len(vals)
    # the same voxels in a grid with one empty cell around them: identical views
    ref = DensityGrid(h.density.copy(), h.aabb.copy())
    cam = look_at_camera(h.aabb.mean(0) + [0.6, 0.5, 0.4], h.aabb.mean(0))
    assert np.array_equal(_render(ref, cam)[0], _render(h, cam)[0])


@needs_vdb
def test_vdb_masked_export_and_rotated_transform_refused(tmp_path):
    g = load_scene(write_vdb(tmp_path / "g.vdb", _grid(rgb=False)))
    sel = np.zeros(g.density.shape, bool)
    sel[:, :, :3] = True
    out = tmp_path / "sel.vdb"
    res = export_selection(g, sel, out)
    assert res.format == "vdb"
    m = read_vdb(out)
    assert int((m.density > 0).sum()) == int((g.density * sel > 0).sum())
    vdb = openvdb_module()
    grid = vdb.FloatGrid()
    grid.copyFromArray(np.ones((3, 3, 3), np.float32))
    grid.name = "density"
    c, s = np.cos(0.3), np.sin(0.3)
    grid.transform = vdb.createLinearTransform(
        [[c, s, 0, 0], [-s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    )
    vdb.write(str(tmp_path / "rot.vdb"), grids=[grid])
    with pytest.raises(DivasInputError, match="axis-aligned"):
        load_scene(tmp_path / "rot.vdb")


def test_vdb_without_openvdb_is_one_clear_message(tmp_path, monkeypatch):
    p = tmp_path / "x.vdb"
    p.write_bytes(b" BDV" + bytes(60))
    monkeypatch.setattr(openvdb_grid, "openvdb_module", lambda: None)
    with pytest.raises(DivasInputError, match="OpenVDB"):
        load_scene(p)


@needs_vdb
@pytest.mark.parametrize("rgb", [True, False])
def test_vdb_written_without_openvdb_reads_back_through_it(tmp_path, monkeypatch, rgb):
    """The NumPy writer (no module): OpenVDB reads the same voxels, colours and lattice
    as the module's own file; over several leaves and 128-voxel nodes, sides not
    multiples of 8."""
    rng = np.random.default_rng(7)
    shape = (11, 150, 133)
    d = ((rng.random(shape) > 0.9) * rng.uniform(0.5, 9, shape)).astype(np.float32)
    c = rng.random(shape + (3,)).astype(np.float32) if rgb else None
    g = DensityGrid(d, np.array([[-1.0, 0.5, 2.0], [12.3, 15.5, 3.1]]), c)
    finder = openvdb_grid.openvdb_module
    monkeypatch.setattr(openvdb_grid, "openvdb_module", lambda: None)
    mine = write_vdb(tmp_path / "numpy.vdb", g)
    monkeypatch.setattr(openvdb_grid, "openvdb_module", finder)
    theirs = write_vdb(tmp_path / "module.vdb", g)
    a, b = read_vdb(mine), read_vdb(theirs)
    np.testing.assert_allclose(a.aabb, g.aabb, atol=1e-9)
    assert np.array_equal(a.density, g.density) and np.array_equal(a.density, b.density)
    if rgb:
        assert np.array_equal(a.rgb, np.where((d > 0)[..., None], c, 0))
    else:
        assert a.rgb is None
    vdb = finder()
    grid = vdb.read(str(mine), "density")
    assert grid.activeVoxelCount() == int((d > 0).sum())
    assert grid.gridClass == vdb.GridClass.FOG_VOLUME


def test_torch_ngp_checkpoint(tmp_path):
    torch = pytest.importorskip("torch")
    from divas_engine.io.ngp_cascades import dense_to_morton
    from divas_engine.io.torch_ngp import TorchNgpFrame

    bound, H = 2.0, 128
    C = 1 + int(np.ceil(np.log2(bound)))  # renderer.py: self.cascade
    frame = TorchNgpFrame()
    world = np.array([0.4, -0.3, 0.9])
    ngp = np.array([world[1], world[2], world[0]]) * frame.scale  # provider.py, offset 0
    grid = np.zeros((C, H, H, H), np.float32)
    grid[:, :4, :4, :4] = -1.0  # unseen
    for c in range(C):  # raymarching.cu: nx = floor(0.5 * (x / b + 1) * H), b = min(2^c, bound)
        b = min(2.0**c, bound)
        cell = np.floor(0.5 * (ngp / b + 1) * H).astype(int)
        grid[c, cell[0], cell[1], cell[2]] = 50.0 * (c + 1)
    model = {
        "density_grid": torch.from_numpy(dense_to_morton(grid)),
        "density_bitfield": torch.zeros(C * H**3 // 8, dtype=torch.uint8),
        "aabb_train": torch.tensor([-bound] * 3 + [bound] * 3),
    }
    p = tmp_path / "ngp_ep0100.pth"
    torch.save({"model": model, "mean_density": 0.001, "epoch": 100}, p)
    g = load_scene(p)
    assert g.source.format == "torch_ngp"
    ijk = np.floor((world - g.aabb[0]) / g.voxel_size).astype(int)
    assert g.density[ijk[2], ijk[1], ijk[0]] == pytest.approx(50.0 * frame.scale)
    sel = np.zeros(g.density.shape, bool)
    out = tmp_path / "masked.pth"
    export_selection(g, sel | (g.density > 0), out)
    back = torch.load(out, weights_only=True)
    assert torch.equal(back["model"]["density_grid"], model["density_grid"])
    export_selection(g, sel, out)
    empty = torch.load(out, weights_only=True)["model"]["density_grid"]
    assert float(empty.max()) == 0.0 and float(empty.min()) == -1.0


def test_colourless_grids_are_shaded_by_their_shape(tmp_path):
    doc, _ = sphere_snapshot(radius_world=0.5, unseen_corner=False)
    p = tmp_path / "s.ingp"
    write_ngp_document(p, doc, True)
    g = load_scene(p)
    assert g.rgb is None and g.network is None
    cam = look_at_camera([2.5, -1.5, 1.0], [0.3, -0.2, 0.1], size=(60, 45), f=60)
    shaded = make_renderer(g).render(cam)
    flat = make_renderer(g, config=RenderConfig(shade_grid=False)).render(cam)
    on = shaded.alpha > 0.9
    assert on.sum() > 100
    assert np.allclose(flat.rgb[on], 0.8 * flat.alpha[on][:, None], atol=1e-3)
    assert shaded.rgb[on].std(0).max() > 0.08  # a ball's colour follows its normal
    # normals point out: the +x side is redder than the −x side
    rgb = shaded_rgb(g)
    idx = np.argwhere(g.density > 0)
    x = idx[:, 2]
    hi = rgb[tuple(idx[x > np.percentile(x, 80)].T)][:, 0].mean()
    lo = rgb[tuple(idx[x < np.percentile(x, 20)].T)][:, 0].mean()
    assert hi > lo + 0.2


def test_cli_on_a_snapshot(tmp_path, capsys):
    from divas_engine.cli import main

    cam = look_at_camera([2.0, -1.0, 1.0], [0.3, -0.2, 0.1], size=(48, 36), f=40, name="t0")
    doc, _ = sphere_snapshot(radius_world=0.4, cameras=[cam], unseen_corner=False)
    p = tmp_path / "s.ingp"
    write_ngp_document(p, doc, True)
    assert main(["info", str(p), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "ingp" and info["camera_count"] == 1 and info["cascades"] == 1
    assert main(["render", str(p), "--index", "0", "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r.png").is_file()
    capsys.readouterr()
    assert main(["anchors", str(p), "--out", str(tmp_path / "a"), "--no-render"]) == 0
    doc = json.loads((tmp_path / "a" / "anchors.json").read_text())
    assert doc["cameras_file"] == "scene file"
    # segment through the snapshot's own camera (the oracle on the ball's voxels)
    g = load_scene(p)
    np.save(tmp_path / "gt.npy", g.density > 0)
    uv, _ = cam.project(np.array([[0.3, -0.2, 0.1]]))
    prompts = {
        "version": 1,
        "anchors": [{"training_camera": "t0", "clicks": [{"xy": uv[0].tolist()}]}],
    }
    (tmp_path / "p.json").write_text(json.dumps(prompts))
    out = tmp_path / "sel.ingp"
    argv = ["segment", str(p), "--prompts", str(tmp_path / "p.json"), "--out", str(out)]
    argv += ["--segmenter", "oracle", "--gt-labels", str(tmp_path / "gt.npy"), "--no-progress"]
    assert main(argv) == 0
    m = load_scene(out)
    assert m.source.format == "ingp" and 0 < int((m.density > 0).sum()) < int((g.density > 0).sum())
