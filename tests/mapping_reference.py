"""NumPy reference of the 2DGS voxel-to-surfel mapping, written straight from
alg:vox2surfel (paper Sec. 3.6) in float64 world space — an independent derivation of
what ``divas_engine.mapping`` computes with the rasterizer's camera-space splat rows in
float32.

Pass 3 here: project the centre and the four 1σ tangent tips with ``Camera.project``,
take the box of pixel centres within ``c ± e``, intersect each pixel's world ray with
the surfel plane and accept ``u² + v² ≤ 9`` with ``u, v`` the hit's tangent coordinates
in units of the scales.

Because the two implementations round differently, a decision that lies within a
tolerance of its threshold (``ρ ≈ 9``, a box edge ≈ a pixel centre, the near-plane
margin ≈ 0) is flagged per surfel in ``ambiguous``; tests compare exactly everywhere
else (and the chosen cases have none).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from divas_engine.fusion.occupancy import GridGeometry, voxel_codes_numpy
from divas_engine.geometry import quat_to_rotmat
from divas_engine.mapping.config import MappingConfig
from divas_engine.scene import SurfelScene

RHO_TOL = 1e-3  # relative, on u² + v² vs accept_sigma²
PX_TOL = 2e-3  # pixels, on box edges
CHUNK = 1 << 22  # (surfel, pixel) pairs per vectorised chunk


def _bit(vmask: np.ndarray, rows: np.ndarray, slot: int) -> np.ndarray:
    return ((vmask[rows, slot // 32] >> np.uint32(slot % 32)) & np.uint32(1)).astype(bool)


def _near_int(x: np.ndarray) -> np.ndarray:
    return np.abs(x - np.rint(x)) < PX_TOL


def map_reference(
    scene: SurfelScene,
    geometry: GridGeometry,
    active_codes: np.ndarray,
    segmented: np.ndarray,
    vmask: np.ndarray,
    views: Sequence,
    slots: Sequence[int],
    config: MappingConfig = MappingConfig(),
) -> dict:
    """The mapping of ``scene`` given the active voxels (``active_codes``, ascending),
    their segmentation flags and ``[A, words]`` view bitmask.

    Returns a dict: ``pass1, pass2, selected`` ``[N] bool``, ``kappa`` ``[N] float32``,
    ``tau_a``, ``total_fp, mask_fp`` ``[S, N] int64`` (full sweeps), ``scored`` ``[S, N]
    bool`` (alg:vox2surfel (i)), ``ambiguous`` ``[N] bool``, ``active`` ``[N]`` index.
    """
    n = len(scene)
    means = np.asarray(scene.means, dtype=np.float32).astype(np.float64)
    # ---- Pass 1 (eq:pass1): NaN/AABB filter, Morton code, segmentation bit
    codes = voxel_codes_numpy(
        means, geometry.center, geometry.half_extent, geometry.voxel_size, geometry.resolution
    )
    ac = np.asarray(active_codes, dtype=np.int64)
    pos = np.clip(np.searchsorted(ac, codes), 0, max(len(ac) - 1, 0))
    hit = (codes >= 0) & (len(ac) > 0) & (ac[pos] == codes if len(ac) else False)
    act = np.where(hit, pos, -1)
    seg = np.asarray(segmented, dtype=bool)
    f1 = hit & seg[np.maximum(act, 0)] if len(seg) else np.zeros(n, bool)
    # ---- Pass 2 (eq:aspect, eq:needle, eq:pass-needle)
    s = np.asarray(scene.scales, dtype=np.float32).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = s.max(1) / (s.min(1) + config.aspect_eps)
    fin = np.isfinite(a)
    tau_a = float(np.percentile(a[fin], config.needle_percentile)) if fin.any() else np.inf
    keep = fin & (a <= tau_a)
    f2 = f1 & keep if config.needle_filter else f1.copy()
    # ---- Pass 3 (eq:cov-atomics, eq:kappa, eq:final-F)
    S = len(views)
    kappa = np.zeros(n, np.float32)
    total = np.zeros((S, n), np.int64)
    maskc = np.zeros((S, n), np.int64)
    scored = np.zeros((S, n), bool)
    amb = np.zeros(n, bool)
    rot = np.asarray(scene.quats, dtype=np.float32).astype(np.float64)
    R = quat_to_rotmat(rot)
    t0 = R[:, :, 0] * s[:, :1]
    t1 = R[:, :, 1] * s[:, 1:2]
    acc2 = config.accept_sigma**2
    kmax = max(acc2, config.box_sigma**2)
    tau_m = np.float32(config.mask_threshold)
    vmask = np.asarray(vmask, dtype=np.uint32).reshape(len(ac), -1)
    for si, (view, slot) in enumerate(zip(views, slots)):
        if not config.coverage_filter:
            break
        cam = view.camera
        cidx = np.nonzero(f2)[0]
        cidx = cidx[_bit(vmask, act[cidx], int(slot))]
        scored[si, cidx] = True
        if cidx.size == 0:
            continue
        mu = means[cidx]
        rw = cam.w2c[:3, :3]
        pc = cam.world_to_camera(mu)
        az = t0[cidx] @ rw[2]
        bz = t1[cidx] @ rw[2]
        zr = np.sqrt(kmax * (az * az + bz * bz))
        marg = pc[:, 2] - zr - cam.clip_near(config.near)
        amb[cidx[np.abs(marg) < 1e-5 * np.maximum(np.abs(pc[:, 2]), 1.0)]] = True
        vis = marg > 0
        cidx, mu = cidx[vis], mu[vis]
        if cidx.size == 0:
            continue
        c, _ = cam.project(mu)
        e = np.zeros_like(c)
        for t in (t0[cidx], t1[cidx]):
            for sg in (1.0, -1.0):
                tip, _ = cam.project(mu + sg * config.box_sigma * t)
                e = np.maximum(e, np.abs(tip - c))
        W, H = cam.width, cam.height
        lo = c - e - 0.5
        hi = c + e - 0.5
        edge = _near_int(lo) | _near_int(hi)
        amb[cidx[edge.any(1)]] = True
        x0 = np.maximum(np.ceil(lo[:, 0]), 0).astype(np.int64)
        x1 = np.minimum(np.floor(hi[:, 0]), W - 1).astype(np.int64)
        y0 = np.maximum(np.ceil(lo[:, 1]), 0).astype(np.int64)
        y1 = np.minimum(np.floor(hi[:, 1]), H - 1).astype(np.int64)
        nx = np.maximum(x1 - x0 + 1, 0)
        ny = np.maximum(y1 - y0 + 1, 0)
        npx = nx * ny
        mask = np.asarray(view.mask, dtype=np.float32)
        o = cam.center
        tot_v = np.zeros(len(cidx), np.int64)
        pos_v = np.zeros(len(cidx), np.int64)
        start = 0
        csum = np.cumsum(npx)
        while start < len(cidx):
            base = csum[start - 1] if start else 0
            stop = max(int(np.searchsorted(csum, base + CHUNK, side="right")), start + 1)
            sl = slice(start, stop)
            k = npx[sl]
            tot_pairs = int(k.sum())
            start = stop
            if tot_pairs == 0:
                continue
            rid = np.repeat(np.arange(sl.start, sl.stop), k)
            local = np.arange(tot_pairs) - np.repeat(np.cumsum(k) - k, k)
            px = x0[rid] + local % nx[rid]
            py = y0[rid] + local // nx[rid]
            d = cam.ray_directions(np.stack([px + 0.5, py + 0.5], -1))
            g = cidx[rid]
            nrm = R[g, :, 2]
            den = np.einsum("ij,ij->i", d, nrm)
            with np.errstate(divide="ignore", invalid="ignore"):
                tt = np.einsum("ij,ij->i", means[g] - o, nrm) / den
                X = o + tt[:, None] * d - means[g]
                u = np.einsum("ij,ij->i", X, R[g, :, 0]) / s[g, 0]
                v = np.einsum("ij,ij->i", X, R[g, :, 1]) / s[g, 1]
                rho = u * u + v * v
            rho = np.where(den != 0, rho, np.inf)
            near9 = np.abs(rho - acc2) < RHO_TOL * acc2
            amb[np.unique(g[near9])] = True
            ok = rho <= acc2
            fg = mask[py, px] >= tau_m
            tot_v += np.bincount(rid[ok], minlength=len(cidx))
            pos_v += np.bincount(rid[ok & fg], minlength=len(cidx))
        total[si, cidx] = tot_v
        maskc[si, cidx] = pos_v
        ks = pos_v.astype(np.float32) / np.maximum(tot_v, 1).astype(np.float32)
        kappa[cidx] = np.maximum(kappa[cidx], ks)
    if config.coverage_filter:
        sel = f2 & (kappa >= np.float32(config.surfel_coverage))
    else:
        sel = f2.copy()
    return {
        "pass1": f1,
        "pass2": f2,
        "selected": sel,
        "kappa": kappa,
        "tau_a": tau_a,
        "total_fp": total,
        "mask_fp": maskc,
        "scored": scored,
        "ambiguous": amb,
        "active": act,
        "n_needles": int((~keep).sum()),
    }
