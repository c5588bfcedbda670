"""NumPy reference renderers, written straight from NOTES "Depth tuple" (float64).

* :func:`reference_surfels` — brute force: every pixel against every surfel
  (chunks of pixels × all surfels), explicit ray–plane intersection.
* :func:`reference_surfels_pairs` — the same algorithm vectorised over a
  (surfel, pixel) pair list built from per-surfel screen boxes: fast enough for
  benchmark-sized scenes.
* :func:`reference_nerf` — ray marcher over a :class:`DensityGrid`, vectorised
  over rays.

Blend order (both surfel references): ascending planar *centre* depth, ties by
index — the order the tile rasterizer uses (2DGS sorts by centre depth). Samples
are composited front to back with ``w_k = α_k T_k``; after blending element ``k``
traversal stops once ``T < t_min``.
"""

from __future__ import annotations

import numpy as np

from divas_engine.camera import Camera
from divas_engine.render.config import RenderConfig
from divas_engine.scene import DensityGrid, SurfelScene

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_colors(sh: np.ndarray, degree: int, dirs: np.ndarray) -> np.ndarray:
    """``[N,3]`` colour ``max(0, 0.5 + Σ c_lm Y_lm(d))`` for unit directions ``dirs`` ``[N,3]``."""
    sh = np.asarray(sh, dtype=np.float64)
    x, y, z = (dirs[:, i : i + 1] for i in range(3))
    c = SH_C0 * sh[:, 0]
    if degree > 0:
        c = c - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
    if degree > 1:
        xx, yy, zz = x * x, y * y, z * z
        basis = [x * y, y * z, 2 * zz - xx - yy, x * z, xx - yy]
        for j in range(5):
            c = c + SH_C2[j] * basis[j] * sh[:, 4 + j]
    if degree > 2:
        basis = [
            y * (3 * xx - yy),
            x * y * z,
            y * (4 * zz - xx - yy),
            z * (2 * zz - 3 * xx - 3 * yy),
            x * (4 * zz - xx - yy),
            z * (xx - yy),
            x * (xx - 3 * yy),
        ]
        for j in range(7):
            c = c + SH_C3[j] * basis[j] * sh[:, 9 + j]
    return np.maximum(c + 0.5, 0.0)


def _pixel_rays(cam: Camera, xs: np.ndarray, ys: np.ndarray):
    """World unit directions, planar-depth factor cos θ and pixel centres of pixel indices."""
    uv = np.stack([xs + 0.5, ys + 0.5], -1).astype(np.float64)
    d = cam.ray_directions(uv)
    cos = d @ cam.forward
    return d, cos, uv


def _composite(
    alpha: np.ndarray,
    depth: np.ndarray,
    feats: np.ndarray,
    cfg: RenderConfig,
    anchor: str,
    bg: np.ndarray,
) -> dict[str, np.ndarray]:
    """Blend ``[P, K]`` elements (front to back along axis 1; ``alpha == 0`` = skipped).

    ``feats`` is ``[P, K, C]``. Returns the NOTES depth tuple, ``alpha`` and ``feat``.
    """
    P, K = alpha.shape
    contrib = alpha >= cfg.alpha_min
    t_after = np.cumprod(1.0 - alpha, axis=1)
    # stop after the element that brings T below t_min
    stop = t_after < cfg.t_min
    seen_stop_before = np.cumsum(stop, axis=1) - stop
    valid = (seen_stop_before == 0) & (alpha > 0)
    a = np.where(valid, alpha, 0.0)
    t_after = np.cumprod(1.0 - a, axis=1)
    t_before = np.concatenate([np.ones((P, 1)), t_after[:, :-1]], axis=1)
    w = a * t_before
    contrib &= valid
    acc = 1.0 - t_after
    rows = np.arange(P)

    def first(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        has = mask.any(axis=1)
        return has, np.argmax(mask, axis=1)

    out: dict[str, np.ndarray] = {}
    has, k = first(valid & (w >= cfg.tau_sig))
    out["D_min"] = np.where(has, depth[rows, k], 0.0)
    has_med, kmed = first(valid & (acc >= 0.5))
    out["D_med"] = np.where(has_med, depth[rows, kmed], 0.0)
    has_max, kmax = first(valid & (acc >= cfg.tau_cw))
    any_c = contrib.any(axis=1)
    klast = K - 1 - np.argmax(contrib[:, ::-1], axis=1)
    out["D_max"] = np.where(has_max, depth[rows, kmax], np.where(any_c, depth[rows, klast], 0.0))
    ws = w.sum(axis=1)
    out["D_exp"] = np.where(
        ws > 0, (w * np.where(valid, depth, 0.0)).sum(axis=1) / np.maximum(ws, 1e-300), 0.0
    )
    kmw = np.argmax(w, axis=1)
    out["D_mw"] = np.where(w.max(axis=1) > 0, depth[rows, kmw], 0.0)
    has_a, ka = (has_med, kmed) if anchor == "med" else (has_max, kmax)
    upto = np.arange(K)[None, :] <= np.where(has_a, ka, K)[:, None]
    out["N_samp"] = (contrib & upto).sum(axis=1).astype(np.int32)
    t_final = t_after[:, -1] if K else np.ones(P)
    out["alpha"] = 1.0 - t_final
    out["feat"] = np.einsum("pk,pkc->pc", w, feats) + t_final[:, None] * bg[None, :]
    return out


def rendered_mask(scene: SurfelScene, cam: Camera, cfg: RenderConfig) -> np.ndarray:
    """Surfels whose whole cutoff disc (``α ≥ α_min``: ``u²+v² ≤ 2 ln(opacity/α_min)``)
    lies beyond the near plane — the only ones rendered."""
    mu, tu, tv, _, s, op = _surfel_frame(scene)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_cut = np.where(op > cfg.alpha_min, 2.0 * np.log(op / cfg.alpha_min), -1.0)
    fwd = cam.forward
    zc = (mu - cam.center) @ fwd
    zr = np.sqrt(
        np.maximum(rho_cut, 0) * ((s[:, 0] * (tu @ fwd)) ** 2 + (s[:, 1] * (tv @ fwd)) ** 2)
    )
    return (rho_cut > 0) & (zc - zr > cfg.near)


def _surfel_frame(scene: SurfelScene):
    rot = scene.rotations().astype(np.float64)
    return (
        scene.means.astype(np.float64),
        rot[:, :, 0],
        rot[:, :, 1],
        rot[:, :, 2],
        scene.scales.astype(np.float64),
        scene.opacities.astype(np.float64),
    )


def surfel_hits(
    scene: SurfelScene,
    cam: Camera,
    xs: np.ndarray,
    ys: np.ndarray,
    cfg: RenderConfig,
    idx: np.ndarray | None = None,
):
    """``α`` and planar depth ``[P, M]`` of pixels ``(xs, ys)`` against surfels ``idx``.

    Only surfels whose whole cutoff disc lies beyond the near plane are rendered
    (:func:`rendered_mask`). Straight from NOTES: intersect the pixel ray with the surfel
    plane, local
    ``(u, v)`` in units of the scales, ``G = exp(−(u²+v²)/2)``; low-pass
    ``exp(−d²/(2σ²))`` around the projected centre; the larger Gaussian wins (its
    depth: intersection or centre); ``α = min(α_max, opacity · G)``; ``α < α_min``
    or depth < near → 0.
    """
    mu, tu, tv, nrm, s, op = _surfel_frame(scene)
    keep = rendered_mask(scene, cam, cfg)
    if idx is not None:
        mu, tu, tv, nrm, s, op, keep = (a[idx] for a in (mu, tu, tv, nrm, s, op, keep))
    d, cos, uv = _pixel_rays(cam, xs, ys)
    o = cam.center
    fwd = cam.forward
    rel = mu - o  # [M,3]
    denom = d @ nrm.T  # [P,M]
    num = (rel * nrm).sum(1)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / denom
        # X − μ = o + t d − μ
        off_u = t * (d @ tu.T) - (rel * tu).sum(1)[None, :]
        off_v = t * (d @ tv.T) - (rel * tv).sum(1)[None, :]
        rho3 = (off_u / s[None, :, 0]) ** 2 + (off_v / s[None, :, 1]) ** 2
    rho3 = np.where((denom != 0) & np.isfinite(rho3), rho3, np.inf)
    z3 = t * cos[:, None]
    zc = rel @ fwd
    cuv, _ = cam.project(mu)
    d2 = ((uv[:, None, :] - cuv[None, :, :]) ** 2).sum(-1)
    rho2 = d2 / cfg.lowpass_sigma**2
    use3 = rho3 <= rho2
    rho = np.where(use3, rho3, rho2)
    z = np.where(use3, z3, zc[None, :])
    with np.errstate(over="ignore", invalid="ignore"):
        alpha = np.minimum(cfg.alpha_max, op[None, :] * np.exp(-0.5 * rho))
    alpha = np.where(
        keep[None, :] & np.isfinite(rho) & (alpha >= cfg.alpha_min) & (z >= cfg.near), alpha, 0.0
    )
    return alpha, np.where(alpha > 0, z, 0.0), zc


def _surfel_colors(scene: SurfelScene, cam: Camera) -> np.ndarray:
    dirs = scene.means.astype(np.float64) - cam.center
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return sh_colors(scene.sh, scene.sh_degree, dirs)


def reference_surfels(
    scene: SurfelScene,
    cam: Camera,
    cfg: RenderConfig | None = None,
    values: np.ndarray | None = None,
    chunk: int = 256,
) -> dict[str, np.ndarray]:
    """Brute-force render: dict of ``[H,W]`` channels (``feat`` ``[H,W,C]``)."""
    cfg = cfg or RenderConfig()
    n = len(scene)
    zc = scene.means.astype(np.float64) @ cam.w2c[2, :3] + cam.w2c[2, 3]
    order = np.lexsort((np.arange(n), zc))
    if values is None:
        feats, bg = _surfel_colors(scene, cam), np.asarray(cfg.background, np.float64)
    else:
        feats = np.asarray(values, np.float64).reshape(n, -1)
        bg = np.zeros(feats.shape[1])
    feats = feats[order]
    ys, xs = np.mgrid[0 : cam.height, 0 : cam.width]
    xs, ys = xs.ravel(), ys.ravel()
    parts = []
    for lo in range(0, len(xs), chunk):
        a, z, _ = surfel_hits(scene, cam, xs[lo : lo + chunk], ys[lo : lo + chunk], cfg, order)
        f = np.broadcast_to(feats[None], (len(a),) + feats.shape)
        parts.append(_composite(a, z, f, cfg, "med", bg))
    return _assemble(parts, cam)


def _assemble(parts: list[dict], cam: Camera) -> dict[str, np.ndarray]:
    out = {}
    for k in parts[0]:
        v = np.concatenate([p[k] for p in parts])
        out[k] = v.reshape((cam.height, cam.width) + v.shape[1:])
    out["D_ref"] = out["D_med"]
    return out


def random_surfel_scene(
    n: int,
    seed: int = 0,
    sh_degree: int = 3,
    extent: float = 1.0,
    z_range: tuple[float, float] = (2.0, 6.0),
    scale_range: tuple[float, float] = (0.01, 0.15),
) -> SurfelScene:
    """Random surfels in a box in front of the identity camera (test fixture)."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(*z_range, n)
    xy = rng.uniform(-extent, extent, (n, 2)) * z[:, None] / 2.0
    means = np.concatenate([xy, z[:, None]], 1).astype(np.float32)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scales = np.exp(rng.uniform(np.log(scale_range[0]), np.log(scale_range[1]), (n, 2)))
    op = rng.uniform(0.02, 1.0, n)
    k = (sh_degree + 1) ** 2
    sh = rng.normal(scale=0.3, size=(n, k, 3))
    sh[:, 0] = rng.normal(scale=1.0, size=(n, 3))
    return SurfelScene(
        means,
        q.astype(np.float32),
        scales.astype(np.float32),
        op.astype(np.float32),
        sh.astype(np.float32),
        sh_degree,
    )


# --------------------------------------------------------------------------- pair-list reference
def _conservative_rects(scene: SurfelScene, cam: Camera, cfg: RenderConfig):
    """Per-surfel pixel rectangles (x0, x1, y0, y1 inclusive) holding every pixel with
    ``α ≥ α_min``: the bounding box of the projected cutoff ellipse, found by
    maximising ``x/z`` (and ``y/z``) over the disc with Lagrange multipliers (the
    extreme values of a ratio of affine functions on a disc, a quadratic equation),
    united with the low-pass disc and widened by one pixel. Culled surfels
    (:func:`rendered_mask`) get an empty rectangle."""
    mu, tu, tv, _, s, op = _surfel_frame(scene)
    with np.errstate(divide="ignore", invalid="ignore"):
        k2 = np.maximum(np.where(op > cfg.alpha_min, 2.0 * np.log(op / cfg.alpha_min), 0.0), 0.0)
    R = cam.w2c[:3, :3]
    pc = cam.world_to_camera(mu)
    a = (tu * s[:, :1]) @ R.T
    b = (tv * s[:, 1:]) @ R.T
    out = []
    for j, (f, c0) in enumerate(((cam.fx, cam.cx), (cam.fy, cam.cy))):
        # X(u,v) = (pc_j + u a_j + v b_j) / (pc_z + u a_z + v b_z); extremes on the circle
        # solve (N − X D)^2 = k2 |(a_j − X a_z, b_j − X b_z)|^2 for X
        A = pc[:, 2] ** 2 - k2 * (a[:, 2] ** 2 + b[:, 2] ** 2)
        B = pc[:, j] * pc[:, 2] - k2 * (a[:, j] * a[:, 2] + b[:, j] * b[:, 2])
        C = pc[:, j] ** 2 - k2 * (a[:, j] ** 2 + b[:, j] ** 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            sq = np.sqrt(np.maximum(B * B - A * C, 0.0))
            lo, hi = (B - sq) / A, (B + sq) / A
            cen = pc[:, j] / pc[:, 2]
            r2 = cfg.lowpass_sigma * np.sqrt(k2)
        lo = np.minimum(f * lo + c0, f * cen + c0 - r2) - 1.0
        hi = np.maximum(f * hi + c0, f * cen + c0 + r2) + 1.0
        size = cam.width if j == 0 else cam.height
        lo = np.nan_to_num(np.clip(lo, -2, size + 2), nan=size + 2)
        hi = np.nan_to_num(np.clip(hi, -2, size + 2), nan=-2)
        out += [
            np.maximum(np.ceil(lo - 0.5), 0).astype(np.int64),
            np.minimum(np.floor(hi - 0.5), size - 1).astype(np.int64),
        ]
    x0, x1, y0, y1 = out
    x1 = np.where(rendered_mask(scene, cam, cfg), x1, -1)
    return x0, x1, y0, y1


def _pair_hits(
    scene: SurfelScene,
    cam: Camera,
    cfg: RenderConfig,
    sid: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
):
    """``α`` and planar depth of (surfel ``sid``, pixel ``(px, py)``) pairs (same maths as
    :func:`surfel_hits`, one pair per row)."""
    mu, tu, tv, nrm, s, op = (a[sid] for a in _surfel_frame(scene))
    d, cos, uv = _pixel_rays(cam, px, py)
    rel = mu - cam.center
    denom = (d * nrm).sum(1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = (rel * nrm).sum(1) / denom
        ou = t * (d * tu).sum(1) - (rel * tu).sum(1)
        ov = t * (d * tv).sum(1) - (rel * tv).sum(1)
        rho3 = (ou / s[:, 0]) ** 2 + (ov / s[:, 1]) ** 2
    rho3 = np.where((denom != 0) & np.isfinite(rho3), rho3, np.inf)
    zc = rel @ cam.forward
    cuv, _ = cam.project(mu)
    rho2 = ((uv - cuv) ** 2).sum(1) / cfg.lowpass_sigma**2
    use3 = rho3 <= rho2
    rho = np.where(use3, rho3, rho2)
    z = np.where(use3, t * cos, zc)
    with np.errstate(over="ignore", invalid="ignore"):
        alpha = np.minimum(cfg.alpha_max, op * np.exp(-0.5 * rho))
    alpha = np.where(np.isfinite(rho) & (alpha >= cfg.alpha_min) & (z >= cfg.near), alpha, 0.0)
    return alpha, z


def reference_surfels_pairs(
    scene: SurfelScene,
    cam: Camera,
    cfg: RenderConfig | None = None,
    rows: tuple[int, int] | None = None,
    band: int = 32,
) -> dict[str, np.ndarray]:
    """The brute-force reference vectorised over (surfel, pixel) pairs.

    Pairs come from conservative per-surfel rectangles, one band of ``band`` image
    rows at a time; pairs are sorted by (pixel, centre-depth rank) and composited
    with segmented cumulative sums. ``rows=(y0, y1)`` renders only those image
    rows (benchmarks time a subset). Adds ``n_trav``: surfels traversed per pixel.
    """
    cfg = cfg or RenderConfig()
    n = len(scene)
    W = cam.width
    y_lo, y_hi = rows or (0, cam.height)
    zc = scene.means.astype(np.float64) @ cam.w2c[2, :3] + cam.w2c[2, 3]
    rank = np.empty(n, np.int64)
    rank[np.lexsort((np.arange(n), zc))] = np.arange(n)
    colors = _surfel_colors(scene, cam)
    bg = np.asarray(cfg.background, np.float64)
    x0, x1, y0, y1 = _conservative_rects(scene, cam, cfg)
    parts = []
    for b0 in range(y_lo, y_hi, band):
        b1 = min(b0 + band, y_hi)
        ya, yb = np.maximum(y0, b0), np.minimum(y1, b1 - 1)
        sel = np.nonzero((x1 >= x0) & (yb >= ya))[0]
        w_, h_ = (x1 - x0 + 1)[sel], (yb - ya + 1)[sel]
        cnt = w_ * h_
        sid = np.repeat(sel, cnt)
        k = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        px = x0[sid] + k % np.repeat(w_, cnt)
        py = ya[sid] + k // np.repeat(w_, cnt)
        alpha, z = _pair_hits(scene, cam, cfg, sid, px, py)
        keep = alpha > 0
        sid, px, py, alpha, z = sid[keep], px[keep], py[keep], alpha[keep], z[keep]
        pix = (py - b0) * W + px
        o = np.lexsort((rank[sid], pix))
        parts.append(
            _composite_pairs(pix[o], alpha[o], z[o], colors[sid[o]], (b1 - b0) * W, cfg, bg)
        )
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    h = y_hi - y_lo
    out = {k: v.reshape((h, W) + v.shape[1:]) for k, v in out.items()}
    out["D_ref"] = out["D_med"]
    return out


def _composite_pairs(
    pix: np.ndarray,
    alpha: np.ndarray,
    z: np.ndarray,
    feat: np.ndarray,
    P: int,
    cfg: RenderConfig,
    bg: np.ndarray,
) -> dict[str, np.ndarray]:
    """Segmented front-to-back compositing of pairs sorted by (pixel, order)."""
    out = {
        "D_min": np.zeros(P),
        "D_med": np.zeros(P),
        "D_max": np.zeros(P),
        "D_exp": np.zeros(P),
        "D_mw": np.zeros(P),
        "N_samp": np.zeros(P, np.int32),
        "alpha": np.zeros(P),
        "n_trav": np.zeros(P, np.int32),
        "feat": np.tile(bg, (P, 1)),
    }
    if len(pix) == 0:
        return out
    starts = np.r_[0, np.nonzero(np.diff(pix))[0] + 1]
    seg = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(pix)]))
    pid = pix[starts]
    pos = np.arange(len(pix))

    def seg_cumsum(v):
        c = np.cumsum(v)
        return c - np.repeat(c[starts] - v[starts], np.diff(np.r_[starts, len(pix)]))

    la = np.log1p(-alpha)
    t_after = np.exp(seg_cumsum(la))
    stop = t_after < cfg.t_min
    valid = (seg_cumsum(stop.astype(np.int64)) - stop) == 0
    t_before = t_after / (1.0 - alpha)
    w = np.where(valid, alpha * t_before, 0.0)
    acc = 1.0 - t_after
    BIG = len(pix) + 1

    def first(mask):
        f = np.minimum.reduceat(np.where(mask & valid, pos, BIG), starts)
        return f < BIG, np.minimum(f, len(pix) - 1)

    has, f = first(w >= cfg.tau_sig)
    out["D_min"][pid] = np.where(has, z[f], 0.0)
    has_med, fmed = first(acc >= 0.5)
    out["D_med"][pid] = np.where(has_med, z[fmed], 0.0)
    has_max, fmax = first(acc >= cfg.tau_cw)
    last = np.maximum.reduceat(np.where(valid, pos, -1), starts)
    out["D_max"][pid] = np.where(has_max, z[fmax], z[last])
    ws = np.add.reduceat(w, starts)
    out["D_exp"][pid] = np.add.reduceat(w * z, starts) / np.where(ws > 0, ws, 1.0)
    wmax = np.maximum.reduceat(w, starts)
    has_mw, fmw = first(w == wmax[seg])
    out["D_mw"][pid] = np.where(has_mw & (wmax > 0), z[fmw], 0.0)
    upto = pos <= np.where(has_med, fmed, BIG)[seg]
    out["N_samp"][pid] = np.add.reduceat((valid & upto).astype(np.int32), starts)
    out["n_trav"][pid] = np.add.reduceat(valid.astype(np.int32), starts)
    t_final = np.exp(np.add.reduceat(np.where(valid, la, 0.0), starts))
    out["alpha"][pid] = 1.0 - t_final
    out["feat"][pid] = np.add.reduceat(w[:, None] * feat, starts, axis=0) + t_final[:, None] * bg
    return out


# --------------------------------------------------------------------------- NeRF reference
def trilinear(grid: np.ndarray, aabb: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Trilinear sample of a cell-centred ``[D,H,W(,C)]`` grid at world points ``[P,3]``
    (clamp to edge)."""
    D, H, W = grid.shape[:3]
    n = np.array([W, H, D])
    f = (pts - aabb[0]) / ((aabb[1] - aabb[0]) / n) - 0.5
    i0 = np.floor(f).astype(np.int64)
    w = f - i0
    out = 0.0
    for dz in (0, 1):
        for dy in (0, 1):
            for dx in (0, 1):
                ix = np.clip(i0[:, 0] + dx, 0, W - 1)
                iy = np.clip(i0[:, 1] + dy, 0, H - 1)
                iz = np.clip(i0[:, 2] + dz, 0, D - 1)
                wt = (
                    (w[:, 0] if dx else 1 - w[:, 0])
                    * (w[:, 1] if dy else 1 - w[:, 1])
                    * (w[:, 2] if dz else 1 - w[:, 2])
                )
                v = grid[iz, iy, ix]
                out = out + (wt[:, None] * v if v.ndim > 1 else wt * v)
    return out


def march_samples(
    grid: DensityGrid, cam: Camera, xs: np.ndarray, ys: np.ndarray, cfg: RenderConfig
):
    """Per ray: segment list ``(t_mid [P,K], δ [P,K], valid [P,K])``, directions and cos θ.

    Entry ``t0 = max(slab entry, near / cos θ)``, exit = slab exit; segments of
    ``δ = step_scale · min voxel edge`` from ``t0``, the last one ending at the exit."""
    d, cos, _ = _pixel_rays(cam, xs, ys)
    o = cam.center
    lo, hi = grid.aabb
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    par = np.abs(d) <= 1e-12
    inside = (o >= lo) & (o <= hi)
    tmin = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
    tmax = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
    t0 = np.maximum(tmin.max(1), cfg.near / cos)
    t1 = tmax.min(1)
    step = cfg.nerf_step_scale * grid.voxel_size.min()
    n = np.where(t1 > t0, np.ceil((t1 - t0) / step), 0).astype(np.int64)
    K = int(n.max()) if len(n) else 0
    k = np.arange(K)[None, :]
    ta = t0[:, None] + k * step
    tb = np.minimum(ta + step, t1[:, None])
    valid = k < n[:, None]
    return 0.5 * (ta + tb), np.where(valid, tb - ta, 0.0), valid, d, cos


def reference_nerf(
    grid: DensityGrid,
    cam: Camera,
    cfg: RenderConfig | None = None,
    values: np.ndarray | None = None,
    rows: tuple[int, int] | None = None,
    chunk: int = 1024,
) -> dict[str, np.ndarray]:
    """Reference ray-march (no empty-space skipping) of image rows ``rows`` (default all)."""
    cfg = cfg or RenderConfig()
    y0, y1 = rows or (0, cam.height)
    ys, xs = np.mgrid[y0:y1, 0 : cam.width]
    xs, ys = xs.ravel(), ys.ravel()
    if values is None:
        fgrid = grid.rgb
        bg = np.asarray(cfg.background, np.float64)
    else:
        fgrid = np.asarray(values, np.float64).reshape(grid.density.shape + (-1,))
        bg = np.zeros(fgrid.shape[3])
    parts = []
    for lo in range(0, len(xs), chunk):
        tm, dt, valid, d, cos = march_samples(
            grid, cam, xs[lo : lo + chunk], ys[lo : lo + chunk], cfg
        )
        P, K = tm.shape
        pts = cam.center + (tm[..., None] * d[:, None, :]).reshape(-1, 3)
        sigma = trilinear(grid.density.astype(np.float64), grid.aabb, pts).reshape(P, K)
        alpha = np.where(valid, 1.0 - np.exp(-np.maximum(sigma, 0.0) * dt), 0.0)
        if fgrid is None:
            feats = np.broadcast_to(np.asarray(cfg.nerf_color, np.float64), (P, K, 3))
        else:
            feats = trilinear(np.asarray(fgrid, np.float64), grid.aabb, pts).reshape(P, K, -1)
        parts.append(_composite(alpha, tm * cos[:, None], feats, cfg, "max", bg))
    out = {}
    for k in parts[0]:
        v = np.concatenate([p[k] for p in parts])
        out[k] = v.reshape((y1 - y0, cam.width) + v.shape[1:])
    out["D_ref"] = out["D_exp"]
    return out


def random_density_grid(shape=(24, 20, 28), seed: int = 0, rgb: bool = True) -> DensityGrid:
    """Blobby random density (zeros in most cells, so skipping is exercised) with RGB."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    d = gaussian_filter(rng.normal(size=shape), 1.5)
    d = np.where(d > 0.15, (d - 0.15) * 60.0, 0.0).astype(np.float32)
    col = rng.uniform(0, 1, shape + (3,)).astype(np.float32) if rgb else None
    return DensityGrid(d, np.array([[-1.0, -0.8, 2.0], [1.2, 0.9, 4.5]]), col)
