"""Small synthetic fusion cases (analytic depth buffers, no renderer needed).

Scene: a unit sphere at the origin on a floor plane z = −1.2, surfels sampled on both.
Views look at the origin from random directions; depth buffers are ray-cast planar
depths perturbed to exercise every predicate: missing D_min, D_min > D_med
(untrusted), N_samp spikes (layered), far pixels (see-through), holes (invalid).
"""

from __future__ import annotations

import functools

import numpy as np

from divas_engine.camera import Camera
from divas_engine.fusion.views import FusionView
from divas_engine.scene import SurfelScene


def sphere_floor_scene(n: int = 6000, seed: int = 0, scale: float = 0.02) -> SurfelScene:
    rng = np.random.default_rng(seed)
    ns = n * 2 // 3
    p = rng.normal(size=(ns, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    fl = np.c_[rng.uniform(-1.6, 1.6, (n - ns, 2)), np.full(n - ns, -1.2)]
    means = np.r_[p, fl].astype(np.float32)
    quats = np.tile([1.0, 0, 0, 0], (n, 1)).astype(np.float32)
    scales = (rng.uniform(0.5, 1.5, (n, 2)) * scale).astype(np.float32)
    opac = rng.uniform(0.3, 1.0, n).astype(np.float32)
    return SurfelScene(means, quats, scales, opac, np.zeros((n, 1, 3), np.float32), 0)


def _raycast(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Planar depth of the sphere/floor per pixel (0 = miss) and a sphere-hit flag."""
    h, w = cam.height, cam.width
    yy, xx = np.mgrid[0:h, 0:w]
    uv = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], -1)
    d = cam.ray_directions(uv)
    o = cam.center
    b = d @ o
    c = o @ o - 1.0
    disc = b * b - c
    ts = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    ts = np.where(ts > 0, ts, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        tf = (-1.2 - o[2]) / d[:, 2]
    tf = np.where((tf > 0) & np.isfinite(tf), tf, np.inf)
    t = np.minimum(ts, tf)
    fwd = cam.forward
    z = np.where(np.isfinite(t), t * (d @ fwd), 0.0)
    return z.reshape(h, w), (ts <= tf).reshape(h, w) & np.isfinite(ts).reshape(h, w)


def make_view(cam: Camera, rng: np.random.Generator, d_cam: float) -> FusionView:
    z, sph = _raycast(cam)
    h, w = z.shape
    far = rng.random((h, w)) < 0.03
    z = np.where(far & (z > 0), z * 2.5, z)  # see-through-like far pixels
    z = np.where(rng.random((h, w)) < 0.02, 0.0, z)  # holes
    dmed = z.astype(np.float32)
    dmin = dmed * (1 - rng.uniform(0, 0.03, (h, w)))
    dmin = np.where(rng.random((h, w)) < 0.05, dmed * 1.02, dmin)  # untrusted
    dmin = np.where(rng.random((h, w)) < 0.03, 0.0, dmin)  # missing
    dmax = dmed * (1 + rng.uniform(0, 0.04, (h, w)))
    n = rng.poisson(5, (h, w)) + np.where(rng.random((h, w)) < 0.08, 25, 0)
    n = np.where(dmed > 0, n, 0)
    m = np.where(sph, rng.uniform(0.55, 1.0, (h, w)), rng.uniform(0.0, 0.45, (h, w)))
    flip = rng.random((h, w)) < 0.05
    m = np.where(flip, 1.0 - m, m)
    return FusionView(
        cam,
        m.astype(np.float32),
        dmin.astype(np.float32),
        dmed,
        dmax.astype(np.float32),
        n.astype(np.float32),
        d_cam,
    )


def random_views(
    k: int,
    seed: int = 1,
    size: tuple[int, int] = (64, 48),
    zoom_every: int = 2,
    zoom_size: tuple[int, int] = (96, 72),
    zoom_fx: float = 250.0,
) -> list[FusionView]:
    """``k`` views at distance 3.5; every ``zoom_every``-th one zoomed in (long focal)."""
    rng = np.random.default_rng(seed)
    views = []
    for i in range(k):
        d = rng.normal(size=3)
        d[2] = abs(d[2]) + 0.3
        d /= np.linalg.norm(d)
        eye = 3.5 * d
        target = rng.normal(scale=0.3, size=3)
        zoom = bool(zoom_every) and i % zoom_every == 1
        wh = zoom_size if zoom else size
        cam = Camera.look_at(
            eye,
            target,
            np.array([0, 0, 1.0]),
            width=wh[0],
            height=wh[1],
            fx=zoom_fx if zoom else 60.0,
            name=f"v{i}",
        )
        views.append(make_view(cam, rng, float(np.linalg.norm(eye - target))))
    return views


# --- one voxel, one view: constructed cases for the gate tests -------------------------
def axis_camera(width: int = 41, height: int = 41, f: float = 100.0) -> Camera:
    """Camera at the origin looking down +z; pixel (w//2, h//2) is centred on the axis."""
    return Camera(width, height, f, f, width / 2.0, height / 2.0, np.eye(4), "axis")


def const_view(cam: Camera, dmed, dmin=None, dmax=None, n=5, mask=0.9, d_cam=4.0) -> FusionView:
    """A view whose buffers are constants or arrays (broadcast to the image)."""
    shape = (cam.height, cam.width)

    def arr(x, dt=np.float32):
        return np.broadcast_to(np.asarray(x, dtype=dt), shape).copy()

    dmed = arr(dmed)
    dmin = arr(dmed - 0.001 if dmin is None else dmin)
    dmax = arr(dmed + 0.002 if dmax is None else dmax)
    return FusionView(cam, arr(mask), dmin, dmed, dmax, arr(n), float(d_cam))


def one_voxel_grid(xc, h: float, rho: float = 1.0, device="cpu"):
    """An OccupancyGrid holding the single voxel of edge ``h`` centred at ``xc``."""
    from divas_engine.fusion.occupancy import GridGeometry, OccupancyGrid

    geo = GridGeometry(np.asarray(xc, dtype=np.float64), h / 2.0, float(h), 1, 1.0, 0.0, False)
    return OccupancyGrid.from_codes(geo, np.array([0]), np.array([rho]), device=device)


def gs_contrib(xc, h: float, view: FusionView, cfg, rho: float = 1.0):
    """(num, den, kind) of one voxel in one view through the Warp kernel."""
    from divas_engine.fusion.gs_fusion import GsFusion

    num, den, kind = GsFusion(one_voxel_grid(xc, h, rho), cfg).contributions(view)
    return float(num[0]), float(den[0]), int(kind[0])


def checker(shape, a: int, b: int) -> np.ndarray:
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    return np.where((xx + yy) % 2 == 0, a, b)


@functools.lru_cache(maxsize=1)
def nerf_case():
    """A 48³ density grid (sphere shell + floor slab), its occupancy and 6 views."""
    from divas_engine.fusion.config import nerf_preset
    from divas_engine.fusion.nerf_occupancy import build_nerf_occupancy
    from divas_engine.scene import DensityGrid

    n = 48
    ax = (np.arange(n) + 0.5) / n * 4 - 2
    z, y, x = np.meshgrid(ax, ax, ax, indexing="ij")
    r = np.sqrt(x**2 + y**2 + z**2)
    dens = (60 * np.exp(-(((r - 1) / 0.08) ** 2))).astype(np.float32)
    dens[np.abs(z + 1.2) < 0.05] += 40
    cfg = nerf_preset("llff", gamma=0.5)
    occ = build_nerf_occupancy(DensityGrid(dens, np.array([[-2, -2, -2], [2, 2, 2.0]])), cfg, "cpu")
    return occ, cfg, random_views(6)
