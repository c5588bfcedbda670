"""``generate_scene(..., kind="3dgs")``: the 3DGS variant as a :class:`SyntheticScene`.

Same layout, cameras, test cameras, click rule and metadata as the 2DGS variant
(``__init__._metadata``), plus the 3DGS ground truth: ``classes`` (what each Gaussian
is), the solids, per-class counts and the shape statistics next to the real captures'
bands (:mod:`.splat_stats`).
"""

from __future__ import annotations

import time

import numpy as np

from ..kinds import SceneKind
from .builder import SceneSpec, choose_clicks
from .gaussians3d import (
    HAZE_SHARE,
    HAZE_SIZE,
    INTERIOR_MARGIN,
    INTERIOR_MAX_SHARE,
    INTERIOR_PACKING,
    INTERIOR_SPACING,
    SURFACE_SCALE,
    GaussianClass,
    build_gaussians3d,
)
from .splat_stats import REAL_BANDS, splat_statistics

__all__ = ["generate_3dgs"]


def generate_3dgs(spec: SceneSpec, size: int, seed: int, sh_degree: int, timings: dict):
    from . import SyntheticScene, _metadata

    t1 = time.perf_counter()
    built = build_gaussians3d(spec, size, seed, sh_degree)
    t2 = time.perf_counter()
    view = built.for_clicks()
    clicks = choose_clicks(seed, spec, view)
    t3 = time.perf_counter()
    meta = _metadata(spec, view, size, seed, sh_degree, clicks)
    # the 2DGS metadata read the click view: put the whole scene's truth back
    meta["target"]["center"] = np.mean(built.centers64[built.labels], axis=0).tolist()
    cls = built.classes
    meta["kind"] = str(SceneKind.GS3D)
    meta["counts"].update(
        {
            "surface": int(np.count_nonzero(cls == GaussianClass.SURFACE)),
            "interior": int(np.count_nonzero(cls == GaussianClass.INTERIOR)),
            "haze": int(np.count_nonzero(cls == GaussianClass.HAZE)),
            "floaters": int(np.count_nonzero(cls == GaussianClass.FLOATER)),
            "needles": int(built.needles.sum()),
            "target": int(built.labels.sum()),
            "background": int((~built.labels).sum()),
            "target_interior": int(
                np.count_nonzero(built.labels & (cls == GaussianClass.INTERIOR))
            ),
        }
    )
    meta["classes"] = {c.name.lower(): int(c) for c in GaussianClass}
    meta["solids"] = [
        {**so.describe(), "count": int(c)} for so, c in zip(built.solids, built.solid_counts)
    ]
    meta["generator_3dgs"] = {
        "surface_scale": SURFACE_SCALE,
        "interior_spacing_spacings": INTERIOR_SPACING,
        "interior_max_share": INTERIOR_MAX_SHARE,
        "haze_size_medians": list(HAZE_SIZE),
        "interior_margin_spacings": INTERIOR_MARGIN,
        "interior_packing": INTERIOR_PACKING,
        "haze_share": HAZE_SHARE,
    }
    meta["statistics"] = splat_statistics(built.scene)
    meta["real_capture_bands"] = {k: list(v) for k, v in REAL_BANDS.items()}
    meta["files"]["ply_layout"] = "3dgs"
    meta["files"]["classes"] = "classes.npy"
    t4 = time.perf_counter()
    return SyntheticScene(
        spec.name,
        seed,
        size,
        built.scene,
        built.labels,
        built.surface_ids,
        built.needles,
        cls == GaussianClass.FLOATER,
        spec.surfaces,
        spec.cameras,
        spec.test_cameras,
        meta,
        timings={
            **timings,
            "gaussians": t2 - t1,
            "clicks": t3 - t2,
            "metadata": t4 - t3,
        },
        kind=SceneKind.GS3D,
        classes=cls,
        ply_rows=built.rows,
    )
