"""Turn a scene specification (analytic surfaces + cameras) into 2DGS surfels.

Per surface, vectorised: counts ∝ ``density × area`` (largest remainder); area-uniform centres
on the analytic surface; frame (t_u, t_v, n) with n the analytic normal; scales ``0.7 ·
spacing`` with mild noise, limited to 0.45 × the curvature radius; opacity U(0.6, 1); SH DC
colour from ``texture.surface_colors``. ``needle_share`` (2 %) of the surfels are faint
needles (aspect > 1000) — the slivers the paper's Pass 2 (eq:needle, P99 cut) is built for, as
on real captures; fewer or opaque ones would put the P99 cut on genuine surfels.
``floater_share`` faint floaters sit in training-camera frusta away from every surface. Rows
are shuffled with a seeded permutation. The model in full: docs/design-notes.md.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..geometry import quat_to_rotmat, rotmat_to_quat
from ..kinds import SceneKind
from ..scene import SH_C0, SurfelScene, sh_coeff_count
from .surfaces import Surface, min_distance
from .texture import surface_colors

__all__ = [
    "SceneSpec",
    "BuiltScene",
    "build_surfels",
    "allocate_counts",
    "notes_grid_params",
    "visibility",
    "segments_clear",
    "rng_for",
]

SCALE_FACTOR = 0.7


def rng_for(seed: int, *keys: str) -> np.random.Generator:
    """Independent deterministic stream for ``(seed, keys...)``."""
    ent = [int(seed) & 0xFFFFFFFF, (int(seed) >> 32) & 0xFFFFFFFF]
    ent += [zlib.crc32(k.encode()) for k in keys]
    return np.random.default_rng(np.random.SeedSequence(ent))


@dataclass
class SceneSpec:
    """What a named scene contributes: geometry, cameras and a few knobs."""

    name: str
    surfaces: list[Surface]
    cameras: list[Camera]
    test_cameras: list[Camera]
    center: np.ndarray
    forward_facing: bool
    target_description: str
    floater_share: float = 0.005
    needle_share: float = 0.02
    #: extra floaters aimed at ``focus = (point, radius)``: between cameras and target
    focus_floater_share: float = 0.0
    focus: tuple[np.ndarray, float] | None = None
    extra: dict = field(default_factory=dict)


@dataclass
class BuiltScene:
    scene: SurfelScene
    labels: np.ndarray  # [N] bool
    surface_ids: np.ndarray  # [N] int32, −1 for floaters
    needles: np.ndarray  # [N] bool
    floaters: np.ndarray  # [N] bool
    points64: np.ndarray  # [N,3] float64 centres (exactly on the surfaces)
    normals64: np.ndarray  # [N,3] float64 analytic normals (floaters: rotation col 2)
    counts: np.ndarray  # [S] surfels per surface
    spacing: np.ndarray  # [S] sample spacing per surface
    base_spacing: float


def allocate_counts(surfaces: list[Surface], n: int) -> np.ndarray:
    """Surfels per surface: fixed ``share`` first, the rest ∝ density × area."""
    counts = np.zeros(len(surfaces), np.int64)
    fixed = [j for j, s in enumerate(surfaces) if s.share is not None]
    for j in fixed:
        counts[j] = int(round(surfaces[j].share * n))
    rest = n - int(counts.sum())
    free = [j for j in range(len(surfaces)) if j not in fixed]
    w = np.array([surfaces[j].density * surfaces[j].area() for j in free], np.float64)
    exact = rest * w / w.sum()
    base = np.floor(exact).astype(np.int64)
    left = rest - int(base.sum())
    order = np.argsort(-(exact - base), kind="stable")
    base[order[:left]] += 1
    counts[free] = base
    return counts


def surfel_scales(
    rng: np.random.Generator, n: int, spacing: float, rc: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s_u, s_v, rotate)``: scales along t_u (curvature direction) and t_v, and
    whether the tangent frame may be randomly rotated (gently curved patch)."""
    base = SCALE_FACTOR * spacing
    a = rng.uniform(-0.25, 0.25, n)
    g = rng.normal(0.0, 0.1, (n, 2))
    su = base * np.exp(g[:, 0] + a)
    sv = base * np.exp(g[:, 1] - a)
    rotate = np.full(n, rc >= 10.0 * base)
    if math.isfinite(rc):
        lim = 0.45 * rc
        k = su / lim
        over = k > 1.0
        su[over] = lim
        sv[over] *= np.minimum(k[over], 3.0)
    return su, sv, rotate


def _rotations(
    normals: np.ndarray, tangents: np.ndarray, rotate: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    t = tangents - n * np.sum(tangents * n, axis=1, keepdims=True)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    ang = rng.uniform(0.0, 2 * math.pi, len(n))
    ca = np.where(rotate, np.cos(ang), 1.0)[:, None]
    sa = np.where(rotate, np.sin(ang), 0.0)[:, None]
    tu = ca * t + sa * b
    tv = np.cross(n, tu)
    return np.stack([tu, tv, n], axis=2)


def _random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q


def scene_floaters(
    rng: np.random.Generator,
    spec: SceneSpec,
    n_float: int,
    n_focus: int,
    surfaces: list[Surface],
    margin: float,
) -> np.ndarray:
    """``[n_float + n_focus, 3]`` floaters of a scene (2DGS and 3DGS alike): ``n_float``
    anywhere in the training frusta, then ``n_focus`` in front of the spec's focus
    point (30–80 % of its depth), drawn from ``rng`` in that order."""
    fl = [sample_floaters(rng, spec.cameras, n_float, surfaces, margin, spec.center)]
    if n_focus:
        fl.append(
            sample_floaters(
                rng,
                spec.cameras,
                n_focus,
                surfaces,
                margin,
                spec.center,
                focus=spec.focus,
                depth_frac=(0.3, 0.8),
            )
        )
    return np.concatenate(fl)


def sample_floaters(
    rng: np.random.Generator,
    cams: list[Camera],
    n: int,
    surfaces: list[Surface],
    margin: float,
    center: np.ndarray,
    focus: tuple[np.ndarray, float] | None = None,
    depth_frac: tuple[float, float] = (0.15, 0.85),
) -> np.ndarray:
    """``[n,3]`` points in free space inside random training-camera frusta.

    Depth is a fraction of the camera's planar depth of ``center`` (or of the
    focus point, whose projected disc then bounds the pixel choice).
    """
    out, have, tries = [], 0, 0
    R = np.stack([c.c2w[:3, :3] for c in cams])
    T = np.stack([c.c2w[:3, 3] for c in cams])
    while have < n:
        tries += 1
        if tries > 200:
            raise RuntimeError("could not place floaters in free space")
        m = max(64, 2 * (n - have))
        k = rng.integers(0, len(cams), m)
        ref = center if focus is None else focus[0]
        pc = np.einsum("mji,mj->mi", R[k], ref - T[k])  # camera coords of the reference
        zc = pc[:, 2]
        fx = np.array([cams[i].fx for i in k])
        fy = np.array([cams[i].fy for i in k])
        cx = np.array([cams[i].cx for i in k])
        cy = np.array([cams[i].cy for i in k])
        w = np.array([cams[i].width for i in k])
        h = np.array([cams[i].height for i in k])
        if focus is None:
            u, v = rng.random(m) * w, rng.random(m) * h
        else:
            rad = focus[1] * fx / np.maximum(zc, 1e-9)
            a, r = rng.random(m) * 2 * math.pi, np.sqrt(rng.random(m)) * rad
            u = np.clip(fx * pc[:, 0] / zc + cx + r * np.cos(a), 0, w)
            v = np.clip(fy * pc[:, 1] / zc + cy + r * np.sin(a), 0, h)
        z = rng.uniform(*depth_frac, m) * zc
        dcam = np.stack([(u - cx) / fx * z, (v - cy) / fy * z, z], 1)
        p = np.einsum("mij,mj->mi", R[k], dcam) + T[k]
        ok = (zc > 0) & (min_distance(surfaces, p, margin * 1.01) >= margin)
        # in front of the first surface along the camera ray (seen, not buried)
        ok[ok] = segments_clear(p[ok], T[k[ok]], surfaces, steps=64)
        out.append(p[ok])
        have += int(ok.sum())
    return np.concatenate(out)[:n]


def build_surfels(spec: SceneSpec, size: int, seed: int, sh_degree: int = 1) -> BuiltScene:
    surfaces = spec.surfaces
    n_float = int(round(spec.floater_share * size))
    n_focus = int(round(spec.focus_floater_share * size)) if spec.focus is not None else 0
    n_surf = size - n_float - n_focus
    counts = allocate_counts(surfaces, n_surf)
    areas = np.array([s.area() for s in surfaces])
    spacing = np.sqrt(areas / np.maximum(counts, 1))
    dens = [j for j, s in enumerate(surfaces) if s.share is None]
    base_spacing = float(
        math.sqrt(
            sum(surfaces[j].density * areas[j] for j in dens) / max(1, sum(counts[j] for j in dens))
        )
    )

    pts, nrms, rots, su_all, sv_all, sid = [], [], [], [], [], []
    for j, s in enumerate(surfaces):
        if counts[j] == 0:
            continue
        rng = rng_for(seed, spec.name, "surface", s.name)
        smp = s.sample(rng, int(counts[j]))
        su, sv, rot = surfel_scales(rng, int(counts[j]), float(spacing[j]), smp.curvature_radius)
        rots.append(_rotations(smp.normals, smp.tangents, rot, rng))
        pts.append(smp.points)
        nrms.append(smp.normals)
        su_all.append(su)
        sv_all.append(sv)
        sid.append(np.full(int(counts[j]), j, np.int32))
    points = np.concatenate(pts)
    normals = np.concatenate(nrms)
    rotm = np.concatenate(rots)
    su, sv = np.concatenate(su_all), np.concatenate(sv_all)
    surface_ids = np.concatenate(sid)

    # needles (on surfaces; their label is their surface's)
    rng = rng_for(seed, spec.name, "needles")
    n_needle = int(round(spec.needle_share * size))
    needle_idx = rng.choice(n_surf, n_needle, replace=False)
    long = SCALE_FACTOR * spacing[surface_ids[needle_idx]] * rng.uniform(2.0, 5.0, n_needle)
    sv[needle_idx] = long
    su[needle_idx] = long / rng.uniform(1200.0, 4000.0, n_needle)
    needles = np.zeros(n_surf, bool)
    needles[needle_idx] = True

    # floaters (free space, camera frusta)
    rng = rng_for(seed, spec.name, "floaters")
    margin = 3.0 * base_spacing
    fpts = scene_floaters(rng, spec, n_float, n_focus, surfaces, margin)
    nf = len(fpts)
    fq = _random_rotations(rng, nf)
    fsize = SCALE_FACTOR * base_spacing * rng.uniform(1.0, 4.0, (nf, 2))
    fopac = rng.uniform(0.05, 0.2, nf)

    # assemble
    quats = np.concatenate([rotmat_to_quat(rotm), fq]).astype(np.float32)
    fn = quat_to_rotmat(fq)[:, :, 2]
    all_pts = np.concatenate([points, fpts])
    all_nrm = np.concatenate([normals, fn])
    scales = np.concatenate([np.stack([su, sv], 1), fsize]).astype(np.float32)
    rng = rng_for(seed, spec.name, "appearance")
    sopac = rng.uniform(0.6, 1.0, n_surf)
    sopac[needle_idx] = rng_for(seed, spec.name, "needle opacity").uniform(0.02, 0.16, n_needle)
    opac = np.concatenate([sopac, fopac]).astype(np.float32)
    surface_ids = np.concatenate([surface_ids, np.full(nf, -1, np.int32)])
    needles = np.concatenate([needles, np.zeros(nf, bool)])
    floaters = surface_ids < 0
    is_target = np.array([s.target for s in surfaces] + [False])
    labels = is_target[surface_ids]  # index −1 → the appended False

    rgb = np.empty((len(all_pts), 3), np.float32)
    noise_seed = zlib.crc32(f"{spec.name}:{seed}".encode())
    groups: dict[tuple[str, float], list[int]] = {}
    for j, s in enumerate(surfaces):
        groups.setdefault((s.palette, s.tex_scale), []).append(j)
    for (pal, scale), js in groups.items():
        sel = np.flatnonzero(np.isin(surface_ids, js))
        rgb[sel] = surface_colors(all_pts[sel], pal, scale, noise_seed)
    rgb[floaters] = surface_colors(all_pts[floaters], "floater", 0.1, noise_seed)
    k = sh_coeff_count(sh_degree)
    sh = np.empty((len(all_pts), k, 3), np.float32)
    sh[:, 0] = (rgb - 0.5) / SH_C0
    if k > 1:
        sh[:, 1:] = rng.normal(0.0, 0.04, (len(all_pts), k - 1, 3))

    perm = rng_for(seed, spec.name, "order").permutation(len(all_pts))
    scene = SurfelScene(
        all_pts[perm].astype(np.float32),
        quats[perm],
        scales[perm],
        opac[perm],
        sh[perm],
        sh_degree,
        SceneKind.GS2D,
    )
    return BuiltScene(
        scene,
        labels[perm],
        surface_ids[perm],
        needles[perm],
        floaters[perm],
        all_pts[perm],
        all_nrm[perm],
        counts,
        spacing,
        base_spacing,
    )


def notes_grid_params(means: np.ndarray, scales: np.ndarray, forward_facing: bool) -> dict:
    """Occupancy-grid sizing of NOTES "Occupancy" (2DGS, Sec. 3.5) for a surfel set.

    Delegates to the engine's own grid rule so the metadata can never disagree with
    the grid that fusion builds.
    """
    from ..fusion.config import GridConfig
    from ..fusion.occupancy import grid_geometry

    cfg = GridConfig.forward_facing() if forward_facing else GridConfig()
    geo = grid_geometry(means, scales, cfg)
    return {
        "c_scene": geo.center.tolist(),
        "r_fg": geo.r_fg,
        "b": geo.half_extent,
        "s_bar": geo.s_bar,
        "h_v": geo.voxel_size,
        "g": geo.resolution,
        "g_max": cfg.g_max,
        "capped": geo.capped,
    }


def visibility(
    points: np.ndarray,
    normals: np.ndarray,
    cams: list[Camera],
    surfaces: list[Surface],
    *,
    steps: int = 256,
    min_cos: float = 0.2,
    border: float = 16.0,
) -> np.ndarray:
    """``[P, K]`` bool: point p is seen by camera k — in the image (``border`` px in),
    in front, facing it (cos ≥ ``min_cos``) and no surface crosses the segment
    (:func:`segments_clear`; samples within a few steps of p, on its own surface,
    are skipped)."""
    P = len(points)
    vis = np.zeros((P, len(cams)), bool)
    pairs_p, pairs_k = [], []
    for k, cam in enumerate(cams):
        uv, z = cam.project(points)
        inimg = (
            (z > 0)
            & (uv[:, 0] >= border)
            & (uv[:, 0] <= cam.width - border)
            & (uv[:, 1] >= border)
            & (uv[:, 1] <= cam.height - border)
        )
        v = cam.center - points
        cosang = np.sum(v * normals, axis=1) / np.linalg.norm(v, axis=1)
        ok = np.flatnonzero(inimg & (cosang >= min_cos))
        pairs_p.append(ok)
        pairs_k.append(np.full(len(ok), k))
    pp, kk = np.concatenate(pairs_p), np.concatenate(pairs_k)
    if len(pp) == 0:
        return vis
    centers = np.stack([c.center for c in cams])
    v = centers[kk] - points[pp]
    cosang = np.sum(v * normals[pp], axis=1) / np.linalg.norm(v, axis=1)
    clear = segments_clear(
        points[pp],
        centers[kk],
        surfaces,
        steps=steps,
        start_skip_steps=3.0 / np.maximum(cosang, min_cos),
    )
    vis[pp[clear], kk[clear]] = True
    return vis


def segments_clear(
    starts: np.ndarray,
    ends: np.ndarray,
    surfaces: list[Surface],
    *,
    steps: int = 256,
    start_skip_steps: np.ndarray | float = 0.0,
) -> np.ndarray:
    """``[M]`` bool: no surface crosses the segment ``starts[i] → ends[i]``.

    Samples every ``L/steps``; a sample closer than 0.6 step to a surface blocks,
    so every crossing surface is caught (the crossing lies within half a step of
    a sample). Samples within ``start_skip_steps`` × 0.6 step of the start are
    ignored (the start's own surface).
    """
    v = ends - starts
    L = np.linalg.norm(v, axis=1)
    d = v / np.maximum(L, 1e-300)[:, None]
    delta = 0.6 * L / steps
    t_ex = np.asarray(start_skip_steps, np.float64) * delta
    frac = (np.arange(steps) + 0.5) / steps
    blocked = np.zeros(len(starts), bool)
    cutoff = float(delta.max()) * 1.01 if len(delta) else 0.0
    for chunk in np.array_split(np.arange(steps), max(1, steps // 32)):
        t = L[:, None] * frac[chunk][None, :]
        q = starts[:, None, :] + d[:, None, :] * t[..., None]
        dist = min_distance(surfaces, q.reshape(-1, 3), cutoff).reshape(len(starts), len(chunk))
        blocked |= ((dist < delta[:, None]) & (t > np.broadcast_to(t_ex, L.shape)[:, None])).any(1)
    return ~blocked


def choose_clicks(
    seed: int,
    spec: SceneSpec,
    built: BuiltScene,
    k: int = 4,
    n_candidates: int = 160,
    n_cams: int = 12,
) -> list[dict]:
    """A few target points that scripted demos can click: well visible, spread out."""
    rng = rng_for(seed, spec.name, "clicks")
    tgt = np.flatnonzero(built.labels & ~built.needles)
    cand = rng.choice(tgt, min(n_candidates, len(tgt)), replace=False)
    cams = spec.cameras
    sub = [cams[i] for i in np.unique(np.linspace(0, len(cams) - 1, n_cams).round().astype(int))]
    vis = visibility(built.points64[cand], built.normals64[cand], sub, spec.surfaces)
    score = vis.sum(1)
    if score.max() == 0:
        raise RuntimeError(f"{spec.name}: no target point is visible from the training cameras")
    good = np.flatnonzero(score >= max(1, 0.5 * score.max()))
    chosen = [good[np.argmax(score[good])]]
    while len(chosen) < min(k, len(good)):
        p = built.points64[cand[good]]
        dmin = np.min(np.linalg.norm(p[:, None] - built.points64[cand[chosen]][None], axis=2), 1)
        chosen.append(good[int(np.argmax(dmin))])
    idx = cand[chosen]
    full = visibility(built.points64[idx], built.normals64[idx], cams, spec.surfaces)
    out = []
    for i, row in zip(idx, full):
        s = spec.surfaces[built.surface_ids[i]]
        out.append(
            {
                "xyz": built.points64[i].tolist(),
                "normal": built.normals64[i].tolist(),
                "surface": s.name,
                "part": s.part,
                "visible_in": [cams[j].name for j in np.flatnonzero(row)],
            }
        )
    return out
