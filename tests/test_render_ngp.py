"""The instant-ngp network kernels against a float64 NumPy reference, the ray-marcher against
an analytic medium, and a network's views against the grid it reproduces."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from divas_engine import load_scene
from divas_engine.io.instant_ngp import NgpFrame, write_ngp_document
from divas_engine.io.instant_ngp_writer import BASE_CONFIG, snapshot_document
from divas_engine.render import RenderConfig, make_renderer
from divas_engine.render.ngp_renderer import NgpRenderer, upload_network
from divas_engine.scene import DensityGrid
from divas_engine.synthetic.ngp_snapshot import snapshot_of_grid
from divas_kernels import eval_ngp_points

from .ngp_cases import look_at_camera, small_config
from .ngp_reference import random_network, reference_eval


def _configs():
    hashed = small_config(levels=4, log2_t=10, width=16)
    dense = copy.deepcopy(hashed)
    dense["encoding"]["otype"] = "DenseGrid"
    dense["encoding"]["n_levels"] = 3
    wide = copy.deepcopy(BASE_CONFIG)  # base.json's MLPs (64 wide, 1 and 2 hidden layers)
    wide["encoding"].update(log2_hashmap_size=12, n_levels=6)
    return {"hashed": hashed, "dense": dense, "base_mlps": wide}


@pytest.mark.parametrize("name", list(_configs()))
def test_network_matches_float64_reference(device, name):
    cfg = _configs()[name]
    net, _ = random_network(cfg, aabb_scale=2, seed=7, scale=0.3)
    rng = np.random.default_rng(11)
    pts = net.aabb[0] + rng.random((3000, 3)) * (net.aabb[1] - net.aabb[0])
    d = rng.standard_normal((3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    got = eval_ngp_points(upload_network(net, device), pts, d)
    ref = reference_eval(net, pts, d)
    # float32 kernels vs float64: a few 1e-4 over 64-wide layers
    assert np.allclose(got, ref, rtol=1e-3, atol=1e-3), np.abs(got - ref).max(0)
    assert np.abs(got - ref).mean() < 1e-4
    # the hash collides on the fine levels of the hashed config: both sides used it
    if name == "hashed":
        assert net.grid.level_resolution(3) ** 3 > net.grid.offsets[4] - net.grid.offsets[3]


def _constant_snapshot(tmp_path, frame):
    """σ = 1 per NeRF unit and colour 0.5 everywhere in the unit cube (zero MLPs)."""
    cfg = small_config(levels=2, log2_t=8, width=16)
    net, _ = random_network(cfg, 1, seed=0)
    for m in net.density_layers + net.rgb_layers:
        m[:] = 0
    ot = np.ones((1, 128, 128, 128), np.float32)
    doc = snapshot_document(ot, frame, 1, network=net, config=cfg)
    p = tmp_path / "const.ingp"
    write_ngp_document(p, doc, True)
    return load_scene(p)


def test_march_through_a_constant_medium_is_analytic(device, tmp_path):
    frame = NgpFrame(0.5, (0.5, 0.5, 0.5))  # world [−1, 1]³ is the NeRF unit cube
    g = _constant_snapshot(tmp_path, frame)
    r = NgpRenderer(g, device=device, config=RenderConfig(near=0.01))
    cam = look_at_camera([0.3, -0.2, -3.0], [0.3, -0.2, 0.0], size=(9, 7), f=8.0)
    b = r.render(cam)
    # per pixel: the path through the box, σ_world = 0.5
    ys, xs = np.mgrid[0:7, 0:9]
    rc = np.stack(
        [(xs + 0.5 - cam.cx) / cam.fx, (ys + 0.5 - cam.cy) / cam.fy, np.ones_like(xs)], -1
    )
    dirs = rc / np.linalg.norm(rc, axis=-1, keepdims=True) @ cam.c2w[:3, :3].T
    o = cam.c2w[:3, 3]
    with np.errstate(divide="ignore"):
        ta, tb = (-1 - o) / dirs, (1 - o) / dirs
    t0 = np.minimum(ta, tb).max(-1)
    t1 = np.maximum(ta, tb).min(-1)
    L = np.maximum(t1 - t0, 0)
    k = 0.5
    alpha = 1 - np.exp(-k * L)
    assert np.allclose(b.alpha, alpha, atol=2e-3)
    assert np.allclose(b.rgb, 0.5 * alpha[..., None], atol=2e-3)
    # expected depth of an exponential density over [t0, t1], planar (× cos)
    cos = 1 / np.linalg.norm(rc, axis=-1)
    e_t = t0 + 1 / k - L * np.exp(-k * L) / np.where(alpha > 0, alpha, 1)
    hit = alpha > 0.01
    assert np.allclose(b.D_exp[hit], (e_t * cos)[hit], atol=5e-3)
    ones = r.render_values(cam, np.ones(g.density.shape, np.float32))
    assert np.allclose(ones, b.alpha, atol=2e-3)


def _two_boxes() -> DensityGrid:
    n = 40
    dens = np.zeros((n, n, n), np.float32)
    rgb = np.zeros((n, n, n, 3), np.float32)
    dens[8:20, 10:30, 6:18] = 60.0
    rgb[8:20, 10:30, 6:18] = (0.9, 0.2, 0.1)
    dens[22:34, 12:24, 20:34] = 60.0
    rgb[22:34, 12:24, 20:34] = (0.1, 0.3, 0.9)
    return DensityGrid(dens, np.array([[-1.0, -1, -1], [1, 1, 1]]), rgb)


def test_network_views_look_like_the_grid_they_encode(device, tmp_path):
    src = _two_boxes()
    cam = look_at_camera([2.2, -2.6, 1.4], [0, 0, 0], size=(80, 60), f=70.0)
    doc = snapshot_of_grid(src, [cam], network=True, network_resolution=48)
    p = tmp_path / "boxes.ingp"
    write_ngp_document(p, doc, True)
    g = load_scene(p)
    net_r = make_renderer(g, device=device, config=RenderConfig(nerf_network=True))
    assert isinstance(net_r, NgpRenderer)
    # by default the network draws the views on CUDA, the grid on a CPU
    auto = make_renderer(g, device=device)
    assert isinstance(auto, NgpRenderer) == (str(device).startswith("cuda"))
    a = make_renderer(src, device=device).render(cam)
    b = net_r.render(cam)
    ma, mb = a.alpha > 0.5, b.alpha > 0.5
    assert (ma & mb).sum() / (ma | mb).sum() > 0.9
    both = ma & mb
    assert np.abs(a.rgb[both] - b.rgb[both]).mean() < 0.12
    assert np.abs(a.D_exp[both] - b.D_exp[both]).mean() < 0.05
    # the red box is red and the blue box blue through the network
    red = both & (a.rgb[..., 0] > a.rgb[..., 2])
    assert red.any() and (b.rgb[red][:, 0] > b.rgb[red][:, 2]).mean() > 0.9
    # the grid marched instead of the network: the network's colour baked at the voxels
    c = make_renderer(g, device=device, config=RenderConfig(nerf_network=False))
    assert not isinstance(c, NgpRenderer)
    cb = c.render(cam)
    mc = cb.alpha > 0.5
    assert (mc & mb).sum() / (mc | mb).sum() > 0.9
    assert (cb.rgb[red & mc][:, 0] > cb.rgb[red & mc][:, 2]).mean() > 0.9
