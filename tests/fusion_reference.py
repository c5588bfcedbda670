"""NumPy references of the fusion kernels, written straight from alg:gs-fusion /
alg:gs-thin and alg:nerf-fusion / alg:nerf-thin (float64, vectorised over voxels,
one view at a time), with the same resolutions of the paper's open points as the
kernels (see ``divas_engine.fusion.gs_fusion`` and ``divas_kernels.fusion_nerf``).

Every threshold decision also records its *margin* (relative distance of the two
sides) per voxel, so tests compare the float32 Warp kernels with this float64
reference exactly on every voxel whose decisions are not knife-edge ties.
"""

from __future__ import annotations

import numpy as np

from divas_engine.camera import Camera
from divas_engine.fusion.views import FusionView

TINY = 1e-30


#: The kernels evaluate per-voxel geometry in float64 and the per-pixel thin sweep in
#: float32: a float64 decision's relative gap is scaled up by this factor, so one
#: exclusion threshold (~1e-5) means ~1e-9 for float64 and ~1e-5 for float32 decisions.
F64 = 1e4


class _Margin:
    def __init__(self, n: int) -> None:
        self.m = np.full(n, np.inf)

    def note(self, sel: np.ndarray, gap: np.ndarray, scale: np.ndarray, f64: bool = False) -> None:
        r = np.abs(gap) / (np.abs(scale) + TINY) * (F64 if f64 else 1.0)
        self.m[sel] = np.minimum(self.m[sel], r[sel] if np.ndim(r) else r)

    def note_floor(self, sel: np.ndarray, x: np.ndarray) -> None:
        """A ⌊x⌋ or an integer bound (float64 in the kernels): distance to the nearest integer."""
        self.note(sel, x - np.round(x), np.maximum(np.abs(x), 1.0), f64=True)


def pixel_depths(view: FusionView, px, py, eps):
    dr = view.d_ref[py, px].astype(np.float64)
    dn = view.d_min[py, px].astype(np.float64)
    dx = view.d_max[py, px].astype(np.float64)
    dn = np.where(dn < eps, dr, dn)
    dx = np.where(dx < eps, dr, dx)
    return dn, dr, dx


def depth_gradient(view: FusionView, k: float, eps: float) -> np.ndarray:
    """π_dg (App. D; NOTES relative central differences, k = 400)."""
    h, w = view.d_ref.shape
    yy, xx = np.mgrid[0:h, 0:w]
    dn, dr, dx = pixel_depths(view, xx, yy, eps)
    d = np.where(dr < eps, 0.0, 0.5 * (dn + dx))
    dpx = d[:, np.minimum(np.arange(w) + 1, w - 1)]
    dmx = d[:, np.maximum(np.arange(w) - 1, 0)]
    dpy = d[np.minimum(np.arange(h) + 1, h - 1), :]
    dmy = d[np.maximum(np.arange(h) - 1, 0), :]
    with np.errstate(divide="ignore", invalid="ignore"):
        gx = (dpx - dmx) / (2 * d)
        gy = (dpy - dmy) / (2 * d)
        out = np.exp(-k * (gx * gx + gy * gy))
    return np.where(d < eps, 0.0, out)


def sat(a: np.ndarray) -> np.ndarray:
    s = np.zeros((a.shape[0] + 1, a.shape[1] + 1), dtype=np.int64)
    s[1:, 1:] = a.astype(np.int64).cumsum(0).cumsum(1)
    return s


def box(s: np.ndarray, x0, y0, x1, y1):
    return s[y1 + 1, x1 + 1] - s[y0, x1 + 1] - s[y1 + 1, x0] + s[y0, x0]


def layered_exact(n, area, s1, s2):
    """eq:seethrough n > n̄ + σ_n, evaluated exactly in integers (as the kernel)."""
    d = n.astype(np.int64) * area.astype(np.int64) - s1
    return (d > 0) & (d * d > area.astype(np.int64) * s2 - s1 * s1)


def project(cam: Camera, pts: np.ndarray):
    w2c = cam.w2c
    pc = pts @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return cam.fx * pc[:, 0] / z + cam.cx, cam.fy * pc[:, 1] / z + cam.cy, z


def pixel_rays(cam: Camera, px, py):
    dc = np.stack(
        [(px + 0.5 - cam.cx) / cam.fx, (py + 0.5 - cam.cy) / cam.fy, np.ones(len(px))], -1
    )
    nrm = np.linalg.norm(dc, axis=1)
    return (dc / nrm[:, None]) @ cam.c2w[:3, :3].T, 1.0 / nrm


def unproject(cam: Camera, px, py, z):
    pc = np.stack([(px + 0.5 - cam.cx) / cam.fx * z, (py + 0.5 - cam.cy) / cam.fy * z, z], -1)
    return pc @ cam.c2w[:3, :3].T + cam.c2w[:3, 3]


def footprint(cam: Camera, xc: np.ndarray, half: np.ndarray, eps: float, mg: _Margin):
    """Pixel box of the 8 projected corners (x0, y0, x1, y1) and validity."""
    us, vs, zs = [], [], []
    for j in range(8):
        s = np.array([2 * (j & 1) - 1, 2 * ((j >> 1) & 1) - 1, 2 * ((j >> 2) & 1) - 1], float)
        u, v, z = project(cam, xc + s * half)
        us.append(u), vs.append(v), zs.append(z)
    us, vs, zs = np.array(us), np.array(vs), np.array(zs)
    ok = np.all(zs > eps, axis=0)
    with np.errstate(invalid="ignore"):
        umin, umax, vmin, vmax = us.min(0), us.max(0), vs.min(0), vs.max(0)
        w, h = cam.width, cam.height
        ok &= ~((umax < 0) | (vmax < 0) | (umin >= w) | (vmin >= h))
    for q in (umin, umax, vmin, vmax):
        mg.note_floor(ok, np.where(ok, q, 0.5))
    x0 = np.floor(np.maximum(np.where(ok, umin, 0), 0)).astype(np.int64)
    y0 = np.floor(np.maximum(np.where(ok, vmin, 0), 0)).astype(np.int64)
    x1 = np.minimum(np.floor(np.minimum(np.where(ok, umax, 0), w)), w - 1).astype(np.int64)
    y1 = np.minimum(np.floor(np.minimum(np.where(ok, vmax, 0), h)), h - 1).astype(np.int64)
    return ok, x0, y0, x1, y1


def _centre_and_frame(cam: Camera, xc: np.ndarray, eps: float, mg: _Margin):
    u, v, xd = project(cam, xc)
    front = xd > eps
    with np.errstate(invalid="ignore"):
        inframe = front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    mg.note_floor(front, np.where(front, u, 0.5))
    mg.note_floor(front, np.where(front, v, 0.5))
    px = np.clip(np.floor(np.where(inframe, u, 0)), 0, cam.width - 1).astype(np.int64)
    py = np.clip(np.floor(np.where(inframe, v, 0)), 0, cam.height - 1).astype(np.int64)
    return inframe, px, py, xd


# ---------------------------------------------------------------------------------
# 2DGS (alg:gs-fusion, alg:gs-thin)
# ---------------------------------------------------------------------------------
def gs_view(
    centers: np.ndarray,
    density: np.ndarray,
    h: float,
    view: FusionView,
    cfg,
    return_debug: bool = False,
):
    """One view's (num, den, kind, margin) for every voxel (kind 1 thick, 2 thin)."""
    cam, eps = view.camera, cfg.eps
    a = len(centers)
    mg = _Margin(a)
    num, den, kind = np.zeros(a), np.zeros(a), np.zeros(a, np.uint8)
    inframe, px, py, xd = _centre_and_frame(cam, centers, eps, mg)
    ok, x0, y0, x1, y1 = footprint(cam, centers, np.full(3, 0.5 * h), eps, mg)
    alive = inframe & ok
    n_img = np.rint(view.n_samp).astype(np.int64)
    s1, s2 = sat(n_img), sat(n_img * n_img)
    area = ((x1 - x0 + 1) * (y1 - y0 + 1)).astype(np.float64)
    mean = box(s1, x0, y0, x1, y1) / area
    m = view.mask[py, px].astype(np.float64)
    dmin, dmed, dmax = pixel_depths(view, px, py, eps)
    n = n_img[py, px].astype(np.float64)
    surf = dmed >= eps
    layered = layered_exact(n_img[py, px], area, box(s1, x0, y0, x1, y1), box(s2, x0, y0, x1, y1))
    seethru = dmed > cfg.gamma_st * view.d_cam
    mg.note(alive, dmed - cfg.gamma_st * view.d_cam, dmed + view.d_cam)
    trusted = dmin <= dmed
    front = (layered | seethru) & trusted
    # thick path
    cand = alive & (m >= cfg.m_thick) & surf & trusted
    rd, cos = pixel_rays(cam, px, py)
    o = cam.center
    dmin_r, dmed_r, dmax_r = dmin / cos, dmed / cos, dmax / cos  # eq:planar-to-ray
    dref_r = np.where(front, dmin_r, dmed_r)
    tstar = np.einsum("ij,ij->i", centers - o, rd)
    t_hat = np.clip(tstar, dmin_r, np.maximum(dref_r, dmin_r))
    delta = np.linalg.norm(centers - (o + t_hat[:, None] * rd), axis=1)
    pdg = depth_gradient(view, cfg.k_dg, eps)
    tau_sp = h * pdg[py, px]  # eq:gs-spatial
    mg.note(cand, delta - tau_sp, xd, f64=True)
    tol = cfg.gamma * h / (1.0 + cfg.beta * np.maximum(n - mean, 0.0))  # eq:tightening
    gap = np.where(front, xd - dmin - tol, np.abs(xd - dmed) - tol)  # eq:asym-gate
    mg.note(cand, gap, xd, f64=True)
    acc = cand & (delta <= tau_sp) & (gap <= 0)
    seg_hi = np.maximum(dmax_r, np.maximum(dref_r, dmin_r))  # ordered segment (kernel doc)
    d_ctr = 0.5 * (dmin_r + seg_hi)
    d_hw = np.maximum(0.5 * (seg_hi - dmin_r), eps)
    w = np.exp(-cfg.alpha1 * ((t_hat - d_ctr) / d_hw) ** 2)  # eq:gs-depthweight
    num[acc], den[acc], kind[acc] = (m * w)[acc], w[acc], 1
    # behind-surface gate (eq:behind-gate)
    d_surf = np.where(trusted & seethru, dmin, dmed)
    bgap = xd - d_surf - cfg.behind_margin * h
    rest = alive & ~acc
    mg.note(rest & surf, bgap, xd, f64=True)
    behind = surf & (bgap > 0)
    thin = rest & ~behind & (density >= cfg.rho_thin)
    t = np.zeros(a)
    idx = np.flatnonzero(thin)
    if len(idx):
        t[idx] = _gs_thin(
            view,
            cfg,
            h,
            centers[idx],
            xd[idx],
            x0[idx],
            y0[idx],
            x1[idx],
            y1[idx],
            mean[idx],
            n_img,
            s1,
            s2,
            mg,
            idx,
        )
    tv = thin & (t >= cfg.tau_thin) & (t > 0)
    num[tv], den[tv], kind[tv] = t[tv], 1.0, 2
    if return_debug:
        return num, den, kind, mg.m, dict(thin=thin, t=t, acc=acc, alive=alive, behind=behind)
    return num, den, kind, mg.m


def _gs_thin(view, cfg, h, xc, xd, x0, y0, x1, y1, mean, n_img, s1, s2, mg, gidx):
    """alg:gs-thin for a batch of voxels (sweeps footprint offsets)."""
    cam, eps = view.camera, cfg.eps
    k = len(xc)
    n_depth, n_md = np.zeros(k, np.int64), np.zeros(k, np.int64)
    area_i = (x1 - x0 + 1) * (y1 - y0 + 1)
    b1, b2 = box(s1, x0, y0, x1, y1), box(s2, x0, y0, x1, y1)
    m_max, d2 = np.zeros(k), np.full(k, np.inf)
    for dy in range(int((y1 - y0).max()) + 1):
        for dx in range(int((x1 - x0).max()) + 1):
            s = np.flatnonzero((x0 + dx <= x1) & (y0 + dy <= y1))
            if not len(s):
                continue
            qx, qy = x0[s] + dx, y0[s] + dy
            dmin, dmed, _ = pixel_depths(view, qx, qy, eps)
            valid = dmed >= eps
            n = n_img[qy, qx].astype(np.float64)
            tol = cfg.gamma * h / (1.0 + cfg.beta * np.maximum(n - mean[s], 0.0))
            layered = layered_exact(n_img[qy, qx], area_i[s], b1[s], b2[s])
            # alg:gs-thin: one-sided (eq:asym-gate) on layered pixels only
            gap = np.where(layered, xd[s] - dmin - tol, np.abs(xd[s] - dmed) - tol)
            v_idx = gidx[s[valid]]
            _note_sub(mg, v_idx, gap[valid], xd[s][valid])
            ok = valid & (gap <= 0)
            n_depth[s[ok]] += 1
            m = view.mask[qy, qx].astype(np.float64)
            pos = ok & (m > cfg.m_pos)
            sp = s[pos]
            n_md[sp] += 1
            m_max[sp] = np.maximum(m_max[sp], m[pos])
            z = np.where(layered, dmin, dmed)[pos]
            pw = unproject(cam, qx[pos], qy[pos], z)
            d2[sp] = np.minimum(d2[sp], ((pw - xc[sp]) ** 2).sum(1))  # eq:thin-d2min
    area = ((x1 - x0 + 1) * (y1 - y0 + 1)).astype(np.float64)
    n_min = np.maximum(cfg.n_abs, np.ceil(cfg.rho_occ * area - 1e-4))  # eq:thin-nmin
    with np.errstate(invalid="ignore", divide="ignore"):
        cover = n_md / n_depth  # eq:gs-coverage
    gate = cfg.dist_gate * h
    has = np.isfinite(d2)
    _note_sub(mg, gidx[has], np.sqrt(d2[has]) - gate, xd[has])
    okk = (n_depth >= n_min) & (cover >= cfg.rho_cover) & (d2 <= gate * gate)
    return np.where(okk, m_max, 0.0)  # eq:thin-tthin-gs


def _note_sub(mg: _Margin, idx: np.ndarray, gap: np.ndarray, scale: np.ndarray) -> None:
    if len(idx):
        r = np.abs(gap) / (np.abs(scale) + TINY)
        np.minimum.at(mg.m, idx, r)


# ---------------------------------------------------------------------------------
# NeRF (alg:nerf-fusion, alg:nerf-thin)
# ---------------------------------------------------------------------------------
def nerf_view(centers: np.ndarray, density: np.ndarray, cell: np.ndarray, view: FusionView, cfg):
    cam, eps = view.camera, cfg.eps
    dx_edge = float(np.max(cell))
    a = len(centers)
    mg = _Margin(a)
    num, den, kind = np.zeros(a), np.zeros(a), np.zeros(a, np.uint8)
    inframe, px, py, xd = _centre_and_frame(cam, centers, eps, mg)
    m = view.mask[py, px].astype(np.float64)
    dmin, dexp, dmax = pixel_depths(view, px, py, eps)
    n = np.rint(view.n_samp[py, px]).astype(np.float64)
    cand = inframe & (m >= cfg.m_thick) & (dexp >= eps)
    rd, cos = pixel_rays(cam, px, py)
    lo, hi = np.minimum(dmin, dmax) / cos, np.maximum(dmin, dmax) / cos
    o = cam.center
    t_c = np.clip(np.einsum("ij,ij->i", centers - o, rd), lo, hi)
    delta = np.linalg.norm(centers - (o + t_c[:, None] * rd), axis=1)  # eq:distance_cond
    pdg = depth_gradient(view, cfg.k_dg, eps)
    tau_sp = dx_edge * pdg[py, px] + cfg.lambda_range * (hi - lo)  # eq:dist_tol
    b = np.minimum(cfg.beta * n, cfg.b_max)
    tau_d = (cfg.gamma + b) * dx_edge  # eq:depth_tol
    mg.note(cand, delta - tau_sp, xd)
    mg.note(cand, np.abs(xd - dexp) - tau_d, xd)
    acc = cand & (delta <= tau_sp) & (np.abs(xd - dexp) <= tau_d)  # eq:nerf-accept
    mu, hd = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), eps)
    w = np.exp(-cfg.alpha1 * (np.abs(t_c - mu) / hd) ** 2)  # eq:nerf-vote
    num[acc], den[acc], kind[acc] = (m * w)[acc], w[acc], 1
    thin = inframe & ~acc & (m > cfg.m_thin_gate) & (density >= cfg.rho_thin)
    ok, x0, y0, x1, y1 = footprint(cam, centers, 0.5 * np.asarray(cell, float), eps, mg)
    thin &= ok
    idx = np.flatnonzero(thin)
    t = np.zeros(a)
    if len(idx):
        t[idx] = _nerf_thin(
            view, cfg, dx_edge, xd[idx], x0[idx], y0[idx], x1[idx], y1[idx], mg, idx
        )
    tv = thin & (t >= cfg.tau_thin) & (t > 0)
    num[tv], den[tv], kind[tv] = t[tv], 1.0, 2
    return num, den, kind, mg.m


def _nerf_thin(view, cfg, dx_edge, xd, x0, y0, x1, y1, mg, gidx):
    k = len(xd)
    n_valid, m_max = np.zeros(k, np.int64), np.zeros(k)
    for dy in range(int((y1 - y0).max()) + 1):
        for dx in range(int((x1 - x0).max()) + 1):
            s = np.flatnonzero((x0 + dx <= x1) & (y0 + dy <= y1))
            if not len(s):
                continue
            qx, qy = x0[s] + dx, y0[s] + dy
            m = view.mask[qy, qx].astype(np.float64)
            m_max[s] = np.maximum(m_max[s], m)  # eq:nerf-counters
            dexp = view.d_ref[qy, qx].astype(np.float64)
            b = np.minimum(cfg.beta * np.rint(view.n_samp[qy, qx]), cfg.b_max)
            tol = (2 * cfg.gamma + b) * dx_edge  # eq:nerf-thindepth
            gap = np.abs(xd[s] - dexp) - tol
            c = (m > cfg.m_pos) & (dexp >= cfg.eps)
            _note_sub(mg, gidx[s[c]], gap[c], xd[s][c])
            sup = c & (gap <= 0)  # eq:nerf-support
            n_valid[s[sup]] += 1
    n_pix = ((x1 - x0 + 1) * (y1 - y0 + 1)).astype(np.float64)
    return np.where(n_valid / n_pix >= cfg.rho_cover, m_max, 0.0)  # eq:nerf-thin


# ---------------------------------------------------------------------------------
def fuse(
    view_fn,
    views: list[FusionView],
    slots: list[int] | None = None,
    *,
    eps: float,
    tau_cons: float,
    words: int = 2,
) -> dict:
    """eq:compact-fusion over views with the per-view function ``view_fn(view)``."""
    out = None
    slots = list(range(len(views))) if slots is None else slots
    for s, v in zip(slots, views):
        num, den, kind, mg = view_fn(v)
        if out is None:
            a = len(num)
            out = dict(
                W=np.zeros(a),
                Z=np.zeros(a),
                n_thick=np.zeros(a, np.int32),
                n_thin=np.zeros(a, np.int32),
                vmask=np.zeros((a, words), np.uint32),
                margin=np.full(a, np.inf),
            )
        out["W"] += num
        out["Z"] += den
        out["n_thick"] += kind == 1
        out["n_thin"] += kind == 2
        out["vmask"][kind > 0, s >> 5] |= np.uint32(1 << (s & 31))
        out["margin"] = np.minimum(out["margin"], mg)
    with np.errstate(invalid="ignore", divide="ignore"):
        out["P"] = np.where(out["Z"] > eps, out["W"] / out["Z"], 0.0)
    out["segmented"] = out["P"] >= tau_cons
    return out
