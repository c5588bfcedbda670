"""Synthetic 2DGS, 3DGS (and NeRF-grid) scenes with exact ground truth.

``generate_scene(name, out_dir, size=..., seed=..., kind=...)`` samples surfels on analytic
surfaces (``surfaces.py``) with the surfel model of ``builder.py`` (``kind`` 2DGS, the
default), or writes the same scene as a trained-looking 3DGS (``gaussians3d.py``, statistics of
real captures in ``splat_stats.py``); the named scenes are in ``scenes.py``. Deterministic in
``(name, size, seed, kind)`` and vectorised.

Files written to ``out_dir``: ``scene.ply`` (2DGS-trainer PLY, or the 3DGS reference-trainer
layout for ``kind=3dgs``); ``cameras.json`` / ``test_cameras.json`` (3DGS schema);
``labels.npy`` (bool per row, True = target); ``surface_ids.npy`` (int32 index into
``scene.json["surfaces"]``, −1 floater); ``scene.json`` (counts, surfaces, target, click
points with the cameras that see them, centre/radius, occupancy sizing); 3DGS only
``classes.npy`` (:class:`~.gaussians3d.GaussianClass`) and the shape statistics; ``ribs`` 2DGS
only ``grid.npz`` (``density [D,H,W]``, ``rgb``, ``aabb``) and ``grid_labels.npy``.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..kinds import SceneKind
from ..output_paths import save_npy_atomic, save_npz_atomic, write_json_atomic
from ..scene import DensityGrid, SurfelScene
from .builder import BuiltScene, SceneSpec, build_surfels, choose_clicks, notes_grid_params
from .grid import voxelize
from .scenes import SCENE_BUILDERS, bounding_radius
from .surfaces import Surface

__all__ = ["SCENE_NAMES", "SyntheticScene", "generate_scene", "notes_grid_params", "MIN_SIZE"]

SCENE_NAMES: tuple[str, ...] = tuple(SCENE_BUILDERS)
MIN_SIZE = 2_000


@dataclass(eq=False)
class SyntheticScene:
    """A generated scene and its ground truth (arrays in PLY row order)."""

    name: str
    seed: int
    size: int
    scene: SurfelScene
    labels: np.ndarray
    surface_ids: np.ndarray
    needles: np.ndarray
    floaters: np.ndarray
    surfaces: list[Surface]
    cameras: list[Camera]
    test_cameras: list[Camera]
    metadata: dict
    grid: DensityGrid | None = None
    grid_labels: np.ndarray | None = None
    timings: dict = field(default_factory=dict)
    kind: SceneKind = SceneKind.GS2D
    #: 3DGS only: :class:`~.gaussians3d.GaussianClass` per Gaussian and the stored PLY rows.
    classes: np.ndarray | None = None
    ply_rows: np.ndarray | None = None

    @property
    def center(self) -> np.ndarray:
        return np.asarray(self.metadata["center"])

    @property
    def radius(self) -> float:
        return float(self.metadata["radius"])

    def write(self, out_dir: str | Path) -> list[Path]:
        from ..io.cameras_json import write_cameras_json
        from ..io.ply import write_surfel_ply

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        paths = [
            out / "scene.ply",
            out / "cameras.json",
            out / "test_cameras.json",
            out / "labels.npy",
            out / "surface_ids.npy",
            out / "scene.json",
        ]
        if self.kind == SceneKind.GS3D:
            from ..io.ply import write_ply_rows

            write_ply_rows(paths[0], {"vertex": self.ply_rows})
        else:
            write_surfel_ply(paths[0], self.scene)
        write_cameras_json(paths[1], self.cameras)
        write_cameras_json(paths[2], self.test_cameras)
        save_npy_atomic(paths[3], self.labels.astype(bool))
        save_npy_atomic(paths[4], self.surface_ids.astype(np.int32))
        write_json_atomic(paths[5], _jsonable(self.metadata))
        if self.classes is not None:
            paths.append(out / "classes.npy")
            save_npy_atomic(paths[-1], self.classes.astype(np.uint8))
        if self.grid is not None:
            paths += [out / "grid.npz", out / "grid_labels.npy"]
            save_npz_atomic(
                paths[-2],
                density=self.grid.density.astype(np.float32),
                rgb=self.grid.rgb.astype(np.float32),
                aabb=self.grid.aabb.astype(np.float64),
            )
            save_npy_atomic(paths[-1], self.grid_labels.astype(bool))
        return paths


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, (np.bool_,)):
        return bool(o)
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    return o


def generate_scene(
    name: str,
    out_dir: str | Path | None = None,
    *,
    size: int = 50_000,
    seed: int = 0,
    sh_degree: int | None = None,
    grid_resolution: int = 128,
    kind: SceneKind | str = SceneKind.GS2D,
) -> SyntheticScene:
    """Generate the named synthetic scene; write its files when ``out_dir`` is given.

    Args:
        name: one of :data:`SCENE_NAMES`.
        size: total surfel / Gaussian count (all classes), exact.
        seed: everything random (sampling, textures, jitter, plant layout) follows it.
        sh_degree: SH degree of the colours (0..3; higher bands are small noise);
            default 1 for 2DGS, 3 for 3DGS (what trainers write).
        grid_resolution: cells along the longest side of the ``ribs`` NeRF grid (2DGS).
        kind: ``"2dgs"`` (surfels, default) or ``"3dgs"`` (trained-looking 3D Gaussians,
            :mod:`.gaussians3d`; same surfaces, cameras and test cameras).
    """
    kind = SceneKind(kind)
    if kind not in (SceneKind.GS2D, SceneKind.GS3D):
        raise ValueError(f"kind must be 2dgs or 3dgs, got {kind!r}")
    if sh_degree is None:
        sh_degree = 3 if kind == SceneKind.GS3D else 1
    if name not in SCENE_BUILDERS:
        raise ValueError(f"unknown synthetic scene {name!r}; choose one of {list(SCENE_NAMES)}")
    if int(size) < MIN_SIZE:
        raise ValueError(f"size {size} is too small (minimum {MIN_SIZE} surfels)")
    if not 0 <= int(sh_degree) <= 3:
        raise ValueError(f"sh_degree must be 0..3, got {sh_degree}")
    if int(grid_resolution) < 8:
        raise ValueError(f"grid_resolution must be >= 8, got {grid_resolution}")
    size, seed = int(size), int(seed)
    t0 = time.perf_counter()
    spec: SceneSpec = SCENE_BUILDERS[name](seed, size)
    t1 = time.perf_counter()
    if kind == SceneKind.GS3D:
        from .scene3d import generate_3dgs

        out = generate_3dgs(spec, size, seed, int(sh_degree), {"layout": t1 - t0})
        if out_dir is not None:
            t5 = time.perf_counter()
            out.write(out_dir)
            out.timings["write"] = time.perf_counter() - t5
        return out
    built = build_surfels(spec, size, seed, sh_degree)
    t2 = time.perf_counter()
    clicks = choose_clicks(seed, spec, built)
    t3 = time.perf_counter()
    meta = _metadata(spec, built, size, seed, sh_degree, clicks)
    grid = grid_labels = None
    if name == "ribs":
        # the box spans everything but the floor in front of the stand (cropped: finer cells)
        fg = [s for s in spec.surfaces if s.name != "floor"]
        lo = np.min([s.bounds()[0] for s in fg], axis=0)
        hi = np.max([s.bounds()[1] for s in fg], axis=0)
        pad = 0.02 * float((hi - lo).max())
        fl = built.floaters
        grid, grid_labels = voxelize(
            spec.surfaces,
            np.stack([lo - pad, hi + pad]),
            grid_resolution,
            zlib.crc32(f"{name}:{seed}".encode()),
            floater_points=built.points64[fl],
            floater_opacity=built.scene.opacities[fl],
            floater_rgb=built.scene.base_colors()[fl],
        )
        meta["grid"] = {
            "shape_dhw": list(grid.density.shape),
            "aabb": grid.aabb.tolist(),
            "voxel_size": grid.extras["voxel_size"],
            "sigma_max": grid.extras["sigma_max"],
            "shell_half_width": grid.extras["shell_half_width"],
            "label_voxels": int(grid_labels.sum()),
            "rib_radius_voxels": spec.extra["rib_radius"] / grid.extras["voxel_size"],
        }
    t4 = time.perf_counter()
    out = SyntheticScene(
        name,
        seed,
        size,
        built.scene,
        built.labels,
        built.surface_ids,
        built.needles,
        built.floaters,
        spec.surfaces,
        spec.cameras,
        spec.test_cameras,
        meta,
        grid,
        grid_labels,
        timings={
            "layout": t1 - t0,
            "surfels": t2 - t1,
            "clicks": t3 - t2,
            "metadata+grid": t4 - t3,
        },
    )
    if out_dir is not None:
        t5 = time.perf_counter()
        out.write(out_dir)
        out.timings["write"] = time.perf_counter() - t5
    return out


def _metadata(
    spec: SceneSpec, built: BuiltScene, size: int, seed: int, sh_degree: int, clicks: list[dict]
) -> dict:
    surfaces = spec.surfaces
    tgt = [s for s in surfaces if s.target]
    bg_near = [s for s in surfaces if s.share is None]  # the dome is not "the scene"
    radius = spec.extra.get("radius") or bounding_radius(bg_near, spec.center)
    t_center = np.mean(built.points64[built.labels], axis=0)
    t_radius = bounding_radius(tgt, t_center)
    occ = notes_grid_params(built.scene.means, built.scene.scales, spec.forward_facing)
    surf_meta = []
    for j, s in enumerate(surfaces):
        d = s.describe()
        d.update(
            {
                "count": int(built.counts[j]),
                "density": s.density,
                "share": s.share,
                "spacing": float(built.spacing[j]),
            }
        )
        surf_meta.append(d)
    meta = {
        "version": 1,
        "generator": "divas_engine.synthetic",
        "name": spec.name,
        "seed": seed,
        "size": size,
        "sh_degree": sh_degree,
        "up": [0.0, 0.0, 1.0],
        "forward_facing": spec.forward_facing,
        "center": spec.center.tolist(),
        "radius": float(radius),
        "target": {
            "description": spec.target_description,
            "surfaces": [s.name for s in tgt],
            "center": t_center.tolist(),
            "radius": float(t_radius),
        },
        "counts": {
            "total": len(built.scene),
            "surface": int((~built.floaters).sum()),
            "floaters": int(built.floaters.sum()),
            "needles": int(built.needles.sum()),
            "target": int(built.labels.sum()),
            "background": int((~built.labels).sum()),
            "train_cameras": len(spec.cameras),
            "test_cameras": len(spec.test_cameras),
        },
        "base_spacing": built.base_spacing,
        "occupancy_notes": occ,
        "clicks": clicks,
        "surfaces": surf_meta,
        "files": {
            "ply": "scene.ply",
            "cameras": "cameras.json",
            "test_cameras": "test_cameras.json",
            "labels": "labels.npy",
            "surface_ids": "surface_ids.npy",
        },
    }
    extra = dict(spec.extra)
    if spec.name == "ribs":
        extra["rib_radius_voxels"] = extra["rib_radius"] / occ["h_v"]
        meta["files"].update({"grid": "grid.npz", "grid_labels": "grid_labels.npy"})
    meta[spec.name] = extra
    return meta
