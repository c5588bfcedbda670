"""Shape statistics of trained 3DGS scenes, measured on the real captures in ``tests/data``.

The synthetic 3DGS generator (:mod:`.gaussians3d`) draws its Gaussians from these measurements
and its tests check that a generated scene's statistics fall inside the bands of the real
captures. Everything is scale-free (ratios, logs relative to the scene's median). Per Gaussian,
with sorted standard deviations ``s_max ≥ s_mid ≥ s_min``: ``log_smax_pXX``, ``mid_max_pXX`` /
``min_max_pXX``, the opacity histogram ends, ``large_share``, ``needle_share``, ``smax_nn8_p50``
and ``hidden_share`` (centres no orbit view sees). :data:`REAL_BANDS` span biker, guitar,
playbot and logo (the flattened LOD tiles are reported, not banded); the sampling tables are
their quantile averages with a mean Gaussian copula.

``python -m divas_engine.synthetic.splat_stats [SCENE ...]`` prints the table for the real
captures (default) or the given scene files. Definitions in full: docs/design-notes.md.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from ..scene import SurfelScene

__all__ = [
    "REAL_CAPTURES",
    "REAL_BANDS",
    "QUANTILE_PROBS",
    "LOG_SMAX_QUANTILES",
    "LOG_MID_MAX_QUANTILES",
    "LOG_MIN_MID_QUANTILES",
    "OPACITY_QUANTILES",
    "NEEDLE_RATIO",
    "sorted_scales",
    "splat_statistics",
    "hidden_share",
    "sample_quantiles",
    "quantile_at",
    "COPULA_CORRELATION",
    "sample_shapes",
]

#: Real captures (paths under ``tests/data``) the bands come from.
REAL_CAPTURES: dict[str, str] = {
    "biker": "playcanvas-splats/biker.compressed.ply",
    "guitar": "playcanvas-splats/guitar.compressed.ply",
    "playbot": "playcanvas-sog/playbot_lod3/meta.json",
    "logo": "playcanvas-sog/playcanvas-logo/meta.json",
}
#: Reported beside them, not in the bands (flattened tiles, module docstring).
FLAT_TILES: dict[str, str] = {
    "lod1": "gaussiansplats3d-lod/lod1_tile_0_0.5x.ply",
    "lod2": "gaussiansplats3d-lod/lod2_tile_0.ply",
    "lod3": "gaussiansplats3d-lod/lod3_tile_0.ply",
}

#: ``s_mid / s_max`` below this is a needle.
NEEDLE_RATIO = 0.05

#: Probabilities of the sampling tables below (inverse-CDF sampling, linear between).
QUANTILE_PROBS = (0.0, 0.001, 0.01, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99, 0.999, 1.0)
# Quantiles at QUANTILE_PROBS, mean over the four captures (the ends: 0.1 / 99.9 % stretched
# by the 1–0.1 % step, so the tables are bounded; opacity ends at 0.999).
#: ``log s_max − median``.
LOG_SMAX_QUANTILES = (
    -2.80, -2.25, -1.70, -1.21, -0.93, -0.47, 0.0, 0.43, 0.85, 1.16, 1.75, 2.53, 3.31,
)  # fmt: skip
#: ``log(s_mid / s_max)``.
LOG_MID_MAX_QUANTILES = (
    -6.42, -5.37, -4.32, -3.38, -2.90, -2.21, -1.55, -0.93, -0.47, -0.26, -0.05, -0.004, 0.0,
)  # fmt: skip
#: ``log(s_min / s_mid)`` (guitar's compressed scales reach 0: floored at 1e-3).
LOG_MIN_MID_QUANTILES = (
    -6.91, -5.88, -4.84, -3.78, -3.15, -2.21, -1.35, -0.68, -0.30, -0.17, -0.04, -0.004, 0.0,
)  # fmt: skip
#: Opacity.
OPACITY_QUANTILES = (
    0.001, 0.027, 0.054, 0.105, 0.156, 0.308, 0.532, 0.778, 0.945, 0.979, 0.993, 0.997, 0.999,
)  # fmt: skip
#: Gaussian-copula correlations of (``log s_max``, ``log(s_mid/s_max)``,
#: ``log(s_min/s_mid)``, opacity), from Spearman's ρ_s as ``2 sin(π ρ_s / 6)``, mean over
#: the four captures: needles are longer (−0.27) and fainter (+0.12), flatter Gaussians
#: less elongated (−0.31), large ones fainter (−0.18).
COPULA_CORRELATION = (
    (1.00, -0.27, -0.09, -0.18),
    (-0.27, 1.00, -0.31, 0.12),
    (-0.09, -0.31, 1.00, 0.06),
    (-0.18, 0.12, 0.06, 1.00),
)

#: [min, max] of each statistic over :data:`REAL_CAPTURES` (module docstring).
REAL_BANDS: dict[str, tuple[float, float]] = {}  # filled below from _MEASURED


def sample_quantiles(rng: np.random.Generator, table, n: int) -> np.ndarray:
    """``n`` draws from the distribution whose quantiles at :data:`QUANTILE_PROBS` are
    ``table`` (inverse CDF, linear between the tabulated points)."""
    return quantile_at(rng.random(n), table)


def quantile_at(u: np.ndarray, table) -> np.ndarray:
    """The tabulated distribution's quantile function at probabilities ``u``."""
    return np.interp(u, QUANTILE_PROBS, table)


def sample_shapes(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """``n`` joint draws of a trained Gaussian's shape and opacity: each marginal is its
    measured table, the dependence the measured Gaussian copula
    (:data:`COPULA_CORRELATION`). Keys: ``log_smax`` (relative to the median),
    ``mid_max``, ``min_mid``, ``opacity``."""
    from scipy.special import ndtr

    chol = np.linalg.cholesky(np.asarray(COPULA_CORRELATION))
    u = ndtr(rng.normal(size=(n, 4)) @ chol.T)
    return {
        "log_smax": quantile_at(u[:, 0], LOG_SMAX_QUANTILES),
        "mid_max": np.exp(quantile_at(u[:, 1], LOG_MID_MAX_QUANTILES)),
        "min_mid": np.exp(quantile_at(u[:, 2], LOG_MIN_MID_QUANTILES)),
        "opacity": quantile_at(u[:, 3], OPACITY_QUANTILES),
    }


def sorted_scales(scene: SurfelScene) -> np.ndarray:
    """``[N,3]`` activated standard deviations, largest first (2DGS: third axis 0)."""
    third = np.zeros(len(scene)) if scene.scale_n is None else scene.scale_n
    s = np.concatenate([np.asarray(scene.scales, np.float64), third[:, None]], axis=1)
    return -np.sort(-s, axis=1)


def splat_statistics(scene: SurfelScene, *, nn: bool = True) -> dict[str, float]:
    """The scale-free shape statistics of the module docstring (all but ``hidden_share``).

    ``nn=False`` skips the nearest-neighbour packing statistic (a KD-tree build).
    """
    s = sorted_scales(scene)
    o = np.asarray(scene.opacities, np.float64)
    ls = np.log(np.maximum(s[:, 0], 1e-30))
    med = float(np.median(ls))
    rel = ls - med
    mid = s[:, 1] / s[:, 0]
    thin = s[:, 2] / s[:, 0]
    out: dict[str, float] = {}
    for q in (1, 10, 90, 99):
        out[f"log_smax_p{q:02d}"] = float(np.percentile(rel, q))
    for q in (10, 50, 90):
        out[f"mid_max_p{q}"] = float(np.percentile(mid, q))
        out[f"min_max_p{q}"] = float(np.percentile(thin, q))
    out["opacity_lt_01"] = float(np.mean(o < 0.1))
    out["opacity_ge_09"] = float(np.mean(o >= 0.9))
    out["opacity_p50"] = float(np.median(o))
    large = rel > math.log(3.0)
    out["large_share"] = float(np.mean(large))
    out["large_low_share"] = float(np.mean(large & (o < 0.3)))
    needle = mid < NEEDLE_RATIO
    out["needle_share"] = float(np.mean(needle))
    out["needle_opacity_p50"] = float(np.median(o[needle])) if needle.any() else float("nan")
    if nn:
        from scipy.spatial import cKDTree

        d, _ = cKDTree(scene.means).query(scene.means, k=9)
        out["smax_nn8_p50"] = float(np.median(s[:, 0] / np.maximum(d[:, 8], 1e-30)))
    return out


def hidden_share(
    scene: SurfelScene,
    *,
    views: int = 48,
    resolution: int = 320,
    behind: float = 0.01,
    device=None,
) -> float:
    """Share of centres more than ``behind · r_fg`` behind the rendered median depth
    ``D_med`` in every one of ``views`` Fibonacci orbit views (distance ``2.5 r_fg``
    from the robust centre, 52° field of view). A centre outside a view or where that
    view's ``D_med`` is empty counts as seen by it."""
    from ..camera import Camera
    from ..render import make_renderer
    from ..scene_stats import robust_frame
    from ..views.fibonacci import fibonacci_sphere

    fr = robust_frame(scene.means)
    r = make_renderer(scene, device=device)
    m = np.asarray(scene.means, np.float64)
    best = np.full(len(scene), np.inf)
    for i, d in enumerate(fibonacci_sphere(views)):
        up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
        cam = Camera.look_at(
            fr.center + 2.5 * fr.radius * d,
            fr.center,
            up,
            width=resolution,
            height=resolution,
            fx=resolution / 0.9,
            name=f"orbit_{i}",
        )
        dmed = r.render(cam).D_med
        uv, z = cam.project(m)
        with np.errstate(invalid="ignore"):
            ok = (
                (z > 0.01)
                & (uv[:, 0] >= 0)
                & (uv[:, 0] < resolution)
                & (uv[:, 1] >= 0)
                & (uv[:, 1] < resolution)
            )
        idx = np.flatnonzero(ok)
        px = np.minimum(uv[idx].astype(np.int64), resolution - 1)
        dd = dmed[px[:, 1], px[:, 0]]
        beh = np.where(dd > 0, z[idx] - dd, -np.inf)
        best[idx] = np.minimum(best[idx], beh)
    best[~np.isfinite(best) & (best > 0)] = -np.inf  # never in any view: not "hidden"
    return float(np.mean(best > behind * fr.radius))


# Measured with `python -m divas_engine.synthetic.splat_stats` (hidden_share: 48 views, 320²).
_MEASURED: dict[str, dict[str, float]] = {
    "biker": {
        "log_smax_p01": -1.7567,
        "log_smax_p10": -0.9165,
        "log_smax_p90": 0.8161,
        "log_smax_p99": 1.5761,
        "mid_max_p10": 0.0595,
        "min_max_p10": 0.0133,
        "mid_max_p50": 0.2393,
        "min_max_p50": 0.0536,
        "mid_max_p90": 0.6704,
        "min_max_p90": 0.1972,
        "opacity_lt_01": 0.3451,
        "opacity_ge_09": 0.0808,
        "opacity_p50": 0.1686,
        "large_share": 0.0426,
        "large_low_share": 0.0208,
        "needle_share": 0.0777,
        "needle_opacity_p50": 0.0941,
        "smax_nn8_p50": 1.2685,
        "hidden_share": 0.0713,
    },
    "guitar": {
        "log_smax_p01": -2.3184,
        "log_smax_p10": -1.3562,
        "log_smax_p90": 0.8588,
        "log_smax_p99": 1.5629,
        "mid_max_p10": 0.0435,
        "min_max_p10": 0.003,
        "mid_max_p50": 0.1837,
        "min_max_p50": 0.0292,
        "mid_max_p90": 0.654,
        "min_max_p90": 0.1616,
        "opacity_lt_01": 0.3135,
        "opacity_ge_09": 0.1751,
        "opacity_p50": 0.2353,
        "large_share": 0.0493,
        "large_low_share": 0.0189,
        "needle_share": 0.1241,
        "needle_opacity_p50": 0.0784,
        "smax_nn8_p50": 1.5358,
        "hidden_share": 0.08,
    },
    "playbot": {
        "log_smax_p01": -1.4059,
        "log_smax_p10": -0.7691,
        "log_smax_p90": 0.7689,
        "log_smax_p99": 1.7321,
        "mid_max_p10": 0.0926,
        "min_max_p10": 0.0122,
        "mid_max_p50": 0.3084,
        "min_max_p50": 0.0402,
        "mid_max_p90": 0.7194,
        "min_max_p90": 0.2068,
        "opacity_lt_01": 0.0032,
        "opacity_ge_09": 0.4954,
        "opacity_p50": 0.898,
        "large_share": 0.0461,
        "large_low_share": 0.0243,
        "needle_share": 0.0336,
        "needle_opacity_p50": 0.6431,
        "smax_nn8_p50": 0.6113,
        "hidden_share": 0.013,
    },
    "logo": {
        "log_smax_p01": -1.3013,
        "log_smax_p10": -0.6748,
        "log_smax_p90": 0.943,
        "log_smax_p99": 2.1156,
        "mid_max_p10": 0.0386,
        "min_max_p10": 0.0078,
        "mid_max_p50": 0.1522,
        "min_max_p50": 0.0576,
        "mid_max_p90": 0.4892,
        "min_max_p90": 0.2158,
        "opacity_lt_01": 0.0563,
        "opacity_ge_09": 0.3809,
        "opacity_p50": 0.8253,
        "large_share": 0.0823,
        "large_low_share": 0.0479,
        "needle_share": 0.1322,
        "needle_opacity_p50": 0.6968,
        "smax_nn8_p50": 0.4521,
        "hidden_share": 0.2588,
    },
}


# The flattened LOD tiles (not in the bands), same run:
#   lod1: min_max_p50 0.0, min_max_p90 0.075, needle_share 0.0163, hidden_share 0.0001
#   lod2: min_max_p50 0.0, min_max_p90 0.1312, needle_share 0.011, hidden_share 0.0003
#   lod3: min_max_p50 0.0, min_max_p90 0.1716, needle_share 0.0051, hidden_share 0.0


def _fill_bands() -> None:
    if not _MEASURED:
        return
    for k in next(iter(_MEASURED.values())):
        vals = [m[k] for m in _MEASURED.values()]
        REAL_BANDS[k] = (min(vals), max(vals))


_fill_bands()


def _main(argv: list[str]) -> int:
    from .. import load_scene

    data = Path(__file__).resolve().parents[2] / "tests" / "data"
    todo = {a: a for a in argv} or {
        k: str(data / v) for k, v in {**REAL_CAPTURES, **FLAT_TILES}.items()
    }
    rows = {}
    for name, path in todo.items():
        sc = load_scene(path)
        st = splat_statistics(sc)
        st["hidden_share"] = hidden_share(sc)
        rows[name] = st
        print(name, {k: round(v, 4) for k, v in st.items()}, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
