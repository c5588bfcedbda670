"""Synthetic benchmark scenes (not tests): surfels on the surfaces of a few shapes
that fill the view of :func:`bench_camera`, and a density grid of the same shapes."""

from __future__ import annotations

import numpy as np

from divas_engine.camera import Camera
from divas_engine.geometry import rotmat_to_quat
from divas_engine.scene import DensityGrid, SurfelScene

#: (centre, radius) of the spheres.
SPHERES = (
    ((-1.6, 0.3, 5.0), 1.0),
    ((0.9, 0.2, 4.0), 1.2),
    ((0.2, -1.0, 6.5), 0.9),
    ((2.4, -0.6, 7.0), 0.8),
)


def bench_camera(width: int = 640, height: int = 480) -> Camera:
    """Identity pose looking down +z, 60° horizontal field of view."""
    fx = width / (2 * np.tan(np.radians(30)))
    return Camera(width, height, fx, fx, width / 2, height / 2)


def _frame(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Rotations ``[N,3,3]`` whose third column is ``normals``, random spin about it."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    ang = rng.uniform(0, 2 * np.pi, len(normals))[:, None]
    a = np.cos(ang) * t1 + np.sin(ang) * t2
    b = np.cross(normals, a)
    return np.stack([a, b, normals], axis=2)


#: The room: an axis-aligned box around the camera (x, y, z min / max).
ROOM = ((-6.0, -4.5, -6.0), (6.0, 1.5, 9.0))


def _room_faces(rng: np.random.Generator, counts: np.ndarray):
    lo, hi = np.array(ROOM[0]), np.array(ROOM[1])
    pts, nrm = [], []
    for f, c in enumerate(counts):
        axis, side = divmod(f, 2)
        p = lo + rng.uniform(size=(c, 3)) * (hi - lo)
        p[:, axis] = hi[axis] if side else lo[axis]
        nv = np.zeros(3)
        nv[axis] = -1.0 if side else 1.0  # facing into the room
        pts.append(p)
        nrm.append(np.tile(nv, (c, 1)))
    return pts, nrm


def surfel_scene(
    n: int, seed: int = 0, sh_degree: int = 3, coverage: float = 0.8, opacity_lo: float = 0.9
) -> SurfelScene:
    """``n`` surfels on the six faces of a room around the camera and four spheres.

    Surfels are spread evenly over the surface area; each surfel's 1σ disc area is
    ``coverage ×`` its share of the surface. About half of them lie outside the
    view of :func:`bench_camera` (walls beside and behind it), as in a real capture.
    """
    rng = np.random.default_rng(seed)
    lo, hi = np.array(ROOM[0]), np.array(ROOM[1])
    ext = hi - lo
    face = [
        ext[1] * ext[2],
        ext[1] * ext[2],
        ext[0] * ext[2],
        ext[0] * ext[2],
        ext[0] * ext[1],
        ext[0] * ext[1],
    ]
    areas = np.array(face + [4 * np.pi * r * r for _, r in SPHERES])
    counts = rng.multinomial(n, areas / areas.sum())
    pts, nrm = _room_faces(rng, counts[:6])
    for (cen, r), c in zip(SPHERES, counts[6:]):
        d = rng.normal(size=(c, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pts.append(np.asarray(cen) + r * d)
        nrm.append(d)
    pts, nrm = np.concatenate(pts), np.concatenate(nrm)
    share = np.repeat(areas / np.maximum(counts, 1), counts)
    s = np.sqrt(coverage * share / np.pi)[:, None] * np.exp(rng.normal(0, 0.25, (n, 2)))
    rot = _frame(nrm, rng)
    k = (sh_degree + 1) ** 2
    sh = rng.normal(scale=0.15, size=(n, k, 3))
    base = rng.uniform(0.1, 0.9, (n, 3))
    sh[:, 0] = (base - 0.5) / 0.28209479177387814
    op = rng.uniform(opacity_lo, 1.0, n)
    return SurfelScene(
        pts.astype(np.float32),
        rotmat_to_quat(rot).astype(np.float32),
        s.astype(np.float32),
        op.astype(np.float32),
        sh.astype(np.float32),
        sh_degree,
    )


def density_grid(res: int = 256, seed: int = 0) -> DensityGrid:
    """The spheres as solid density-40 balls (plus sparse floaters) in ``res³`` cells, with RGB."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array([-3.5, -2.5, 2.5]), np.array([3.5, 2.0, 8.5])
    axes = [lo[i] + (np.arange(res) + 0.5) * (hi[i] - lo[i]) / res for i in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    dens = np.zeros((res, res, res), np.float32)
    rgb = np.zeros((res, res, res, 3), np.float32)
    for cen, r in SPHERES:
        inside = (x - cen[0]) ** 2 + (y - cen[1]) ** 2 + (z - cen[2]) ** 2 <= r * r
        dens[inside] = 40.0
        rgb[inside] = rng.uniform(0.2, 0.9, 3)
    dens += (rng.uniform(size=dens.shape) < 2e-5).astype(np.float32) * 5.0  # sparse floaters
    return DensityGrid(dens, np.stack([lo, hi]), rgb)
