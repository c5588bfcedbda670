"""Hand-checkable scenes for the 3D graph segmenter: surfels on a few analytic shapes,
each shape one flat colour, with the shape index of every surfel as ground truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from divas_engine.geometry import rotmat_to_quat
from divas_engine.kinds import SceneKind
from divas_engine.scene import SH_C0, DensityGrid, SurfelScene
from divas_engine.synthetic.surfaces import Cylinder, Frame, Rect, Sphere, Surface, box

__all__ = [
    "Part",
    "CaseScene",
    "GridCase",
    "build_case",
    "touching_boxes",
    "rod_on_floor",
    "ball_on_floor",
    "ball_and_specks",
    "box_and_hanging_plate",
    "ball_with_leaves",
    "grid_ball_and_box",
]

FLOOR_RGB = (0.55, 0.55, 0.5)


@dataclass(frozen=True)
class Part:
    """Surfaces of one shape, its colour, its surfel spacing."""

    surfaces: tuple[Surface, ...]
    rgb: tuple[float, float, float]
    spacing: float = 0.01


@dataclass(eq=False)
class CaseScene:
    scene: SurfelScene
    part: np.ndarray  # [N] index of the part each surfel belongs to

    def of(self, k: int) -> np.ndarray:
        return self.part == k


def _frames(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    return np.stack([t1, t2, normals], axis=2)


def build_case(parts: list[Part], seed: int = 0) -> CaseScene:
    """Surfels on ``parts`` (one every ``spacing``² of area, scale ``0.7 spacing``)."""
    rng = np.random.default_rng(seed)
    pts, nrm, col, scl, ids = [], [], [], [], []
    for k, part in enumerate(parts):
        for s in part.surfaces:
            n = max(8, int(round(s.area() / part.spacing**2)))
            smp = s.sample(rng, n)
            pts.append(smp.points)
            nrm.append(smp.normals)
            col.append(np.tile(part.rgb, (n, 1)))
            scl.append(np.full((n, 2), 0.7 * part.spacing))
            ids.append(np.full(n, k))
    p = np.concatenate(pts).astype(np.float32)
    n = np.concatenate(nrm)
    quats = rotmat_to_quat(_frames(n / np.linalg.norm(n, axis=1, keepdims=True), rng))
    sh = ((np.concatenate(col) - 0.5) / SH_C0)[:, None, :].astype(np.float32)
    scene = SurfelScene(
        p,
        quats.astype(np.float32),
        np.concatenate(scl).astype(np.float32),
        np.full(len(p), 0.9, np.float32),
        sh,
        0,
    )
    return CaseScene(scene, np.concatenate(ids))


def floor(half: float = 1.5, spacing: float = 0.02) -> Part:
    return Part((Rect("floor", Frame.make((0, 0, 0), (0, 0, 1)), half, half),), FLOOR_RGB, spacing)


def touching_boxes(same_colour: bool = False) -> CaseScene:
    """Parts: 0 floor, 1 box A (x < 0), 2 box B (x > 0) touching A along x = 0; B is
    shorter than A so the contact is a step, not a flush face."""
    a = box("a", (-0.15, 0.0, 0.15), (0.15, 0.15, 0.15))
    b = box("b", (0.12, 0.0, 0.1), (0.12, 0.12, 0.1))
    rgb_b = (0.8, 0.3, 0.2) if same_colour else (0.2, 0.35, 0.8)
    return build_case([floor(), Part(tuple(a), (0.8, 0.3, 0.2)), Part(tuple(b), rgb_b)])


def rod_on_floor() -> CaseScene:
    """Parts: 0 floor, 1 a thin vertical rod (radius 1 cm, 0.8 high) with a cap."""
    fr = Frame.make((0.0, 0.0, 0.0), (0, 0, 1))
    rod = Cylinder("rod", fr, 0.01, 0.0, 0.8)
    cap = Sphere("cap", Frame.make((0.0, 0.0, 0.8), (0, 0, 1)), 0.01, 0.0, np.pi / 2)
    return build_case([floor(), Part((rod, cap), (0.3, 0.3, 0.32), 0.004)])


def ball_on_floor() -> CaseScene:
    """Parts: 0 floor, 1 a ball of radius 0.2 resting on it (same grey as the floor). The
    floor's surfels lie closer than the graph's voxels around a click on it (h ≈ 1.4
    cm): a sparser random sampling leaves voxel-wide holes, and a floor in pieces is no
    longer one continuing surface to the cut."""
    ball = Sphere("ball", Frame.make((0.0, 0.0, 0.2), (0, 0, 1)), 0.2)
    return build_case([floor(spacing=0.012), Part((ball,), FLOOR_RGB)])


def ball_and_specks() -> CaseScene:
    """Parts: 0 floor, 1 the grey ball of :func:`ball_on_floor`, 2 loose specks: three
    small cubes (1.5 cm) floating beside and above the ball, touching nothing — bits of
    haze a capture leaves around an object."""
    ball = Sphere("ball", Frame.make((0.0, 0.0, 0.2), (0, 0, 1)), 0.2)
    specks = [
        s
        for c in ((0.3, 0.0, 0.3), (0.0, 0.3, 0.45), (-0.28, -0.1, 0.2))
        for s in box("speck", c, (0.0075, 0.0075, 0.0075))
    ]
    return build_case(
        [floor(), Part((ball,), FLOOR_RGB), Part(tuple(specks), (0.7, 0.6, 0.5), 0.003)]
    )


def box_and_hanging_plate() -> CaseScene:
    """Parts: 0 floor, 1 a red box floating 0.33 above it, 2 a blue slab beside it that
    touches the box only along one vertical edge and nothing else (an occluder that
    hangs on the object in a few voxels)."""
    a = box("a", (0.0, 0.0, 0.45), (0.12, 0.12, 0.12))
    b = box("b", (0.2, 0.2, 0.45), (0.08, 0.08, 0.2))
    return build_case([floor(), Part(tuple(a), (0.8, 0.3, 0.2)), Part(tuple(b), (0.2, 0.35, 0.8))])


def ball_with_leaves(kind: SceneKind = SceneKind.GS3D) -> CaseScene:
    """Parts: 0 floor, 1 the grey ball of :func:`ball_on_floor`, 2 four large round 3DGS
    Gaussians (σ 7 cm on all three axes, no sure normal, the ball's grey-green) around
    the ball like a plant's soft foliage — each centre 4 cm (≈ 3 voxels of a click's
    graph) off the ball's surface, so its 1 σ extent overlaps the ball while its
    centre's voxel touches no other occupied voxel —, 3 one more such Gaussian 30 cm off
    the ball, overlapping nothing. The surfels of 0 and 1 are flat (``scale_n`` 0). A
    trained 3DGS scene by default (``kind``)."""
    base = build_case(
        [
            floor(spacing=0.012),
            Part((Sphere("ball", Frame.make((0.0, 0.0, 0.2), (0, 0, 1)), 0.2),), FLOOR_RGB),
        ]
    )
    c0 = np.array([0.0, 0.0, 0.2])
    dirs = [(1.0, 0.0, 0.3), (-1.0, 0.0, 0.3), (0.0, 1.0, 0.3), (0.0, -1.0, 0.3), (1.0, 1.0, 0.2)]
    offs = [0.04, 0.04, 0.04, 0.04, 0.3]
    pts = [
        c0 + (0.2 + off) * np.asarray(d) / np.linalg.norm(d)
        for d, off in zip(dirs, offs, strict=True)
    ]
    k = len(pts)
    s = base.scene
    rgb = np.array([0.5, 0.6, 0.45])
    scene = SurfelScene(
        np.concatenate([s.means, np.asarray(pts, np.float32)]),
        np.concatenate([s.quats, np.tile(np.float32([1.0, 0.0, 0.0, 0.0]), (k, 1))]),
        np.concatenate([s.scales, np.full((k, 2), 0.07, np.float32)]),
        np.concatenate([s.opacities, np.full(k, 0.9, np.float32)]),
        np.concatenate([s.sh, np.tile(((rgb - 0.5) / SH_C0)[None, None, :], (k, 1, 1))]).astype(
            np.float32
        ),
        0,
        scale_n=np.r_[np.zeros(len(s), np.float32), np.full(k, 0.07, np.float32)],
        kind=kind,
    )
    return CaseScene(scene, np.r_[base.part, [2, 2, 2, 2, 3]])


@dataclass(eq=False)
class GridCase:
    grid: DensityGrid
    part: np.ndarray  # [D,H,W] index of the part each cell belongs to (-1: empty)

    def of(self, k: int) -> np.ndarray:
        return self.part.reshape(-1) == k


def grid_ball_and_box(n: int = 64, sigma: float = 60.0) -> GridCase:
    """A NeRF density grid over ``[-0.5, 0.5]² × [0, 1]``, ``n`` cells a side. Parts: 0 a
    floor slab 4 cells thick, 1 a ball of radius 0.15 resting on it (the floor's grey),
    2 a box beside the ball (red), 3 cm apart. Solid parts hold density ``sigma``."""
    h = 1.0 / n
    c = (np.arange(n) + 0.5) * h
    z, y, x = np.meshgrid(c, c - 0.5, c - 0.5, indexing="ij")
    top = 4 * h
    part = np.full((n, n, n), -1, np.int64)
    part[z < top] = 0
    part[(x**2 + y**2 + (z - top - 0.15) ** 2) <= 0.15**2] = 1
    part[(np.abs(x - 0.28) <= 0.1) & (np.abs(y) <= 0.1) & (z >= top) & (z <= top + 0.2)] = 2
    rgb = np.zeros((n, n, n, 3), np.float32)
    rgb[part == 0] = FLOOR_RGB
    rgb[part == 1] = FLOOR_RGB
    rgb[part == 2] = (0.8, 0.25, 0.2)
    density = np.where(part >= 0, np.float32(sigma), np.float32(0.0))
    aabb = np.array([[-0.5, -0.5, 0.0], [0.5, 0.5, 1.0]])
    return GridCase(DensityGrid(density.astype(np.float32), aabb, rgb), part)
