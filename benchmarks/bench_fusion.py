"""Fusion benchmark: occupancy build, per-update (one new view, incremental) and full
re-fuse (20 views) of the 2DGS and NeRF kernels at 100k / 500k / 2M active voxels,
against the NumPy reference of ``tests/fusion_reference.py``.

Scene: voxels of a unit-sphere shell at g = 1024 (h_v ≈ 0.002), randomly subsampled
to each size so every size has the same per-voxel work (a clean linear-scaling
check). Views: 640×480, 20 cameras at distance 3 around the sphere (half of them
zoomed ×4, like centroid views), analytic depth buffers, a mask covering x > 0.

    python benchmarks/bench_fusion.py [--sizes 100000,500000,2000000] [--device cpu]
                                      [--ref-max 2000000] [--nerf]

"Stream GB/s" counts only the per-voxel arrays each update streams (fuse kernel:
code/index 8|4 B + density 4 B read, num/den/kind 9 B written; compaction and
apply: ~40 B per voxel + ~30 B per record) — a lower bound on the traffic: centre-
pixel gathers, integral-image corners and thin sweeps mostly hit cache.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from divas_engine.camera import Camera  # noqa: E402
from divas_engine.fusion.config import GridConfig, GsFusionConfig, nerf_preset  # noqa: E402
from divas_engine.fusion.gs_fusion import GsFusion  # noqa: E402
from divas_engine.fusion.morton import morton_encode  # noqa: E402
from divas_engine.fusion.nerf_fusion import NerfFusion  # noqa: E402
from divas_engine.fusion.nerf_occupancy import NerfBuildReport, NerfOccupancy  # noqa: E402
from divas_engine.fusion.occupancy import (
    GridGeometry,
    OccupancyGrid,  # noqa: E402
    build_occupancy,
)
from divas_engine.fusion.views import FusionView  # noqa: E402
from divas_engine.scene import SurfelScene  # noqa: E402
from tests import fusion_reference as ref  # noqa: E402

G = 1024
B = 1.05
H = 2 * B / G


def shell_codes(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` voxels (Morton codes) of a watertight one-voxel sphere shell at g = 1024 whose
    radius grows as √n (≈ 3.0M voxels at r = 1), so every size has the same voxel
    density on screen and the same per-voxel work (a clean linear-scaling check)."""
    r = shell_radius(n)
    lo, hi = max(r - H / 2, 0.0), r + H / 2
    m = int(np.ceil(hi / H)) + 1
    c = (np.arange(-m, m) + 0.5) * H
    x, y = np.meshgrid(c, c, indexing="ij")
    rho2 = (x * x + y * y).ravel()
    keep = rho2 < hi * hi
    x, y, rho2 = x.ravel()[keep], y.ravel()[keep], rho2[keep]
    zhi = np.sqrt(hi * hi - rho2)
    zlo = np.sqrt(np.maximum(lo * lo - rho2, 0.0))
    out = []
    for sign in (1.0, -1.0):
        k0 = np.ceil(zlo / H - 0.5).astype(np.int64)  # centres (k + ½)h in [zlo, zhi)
        k1 = np.ceil(zhi / H - 0.5).astype(np.int64)
        cnt = np.maximum(k1 - k0, 0)
        col = np.repeat(np.arange(len(x)), cnt)
        k = np.repeat(k0, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        zc = sign * (k + 0.5) * H
        out.append(np.stack([x[col], y[col], zc], -1))
    p = np.concatenate(out)
    ijk = np.clip(np.floor((p + B) / H), 0, G - 1).astype(np.int64)
    codes = np.unique(morton_encode(ijk))
    if len(codes) < n:
        raise RuntimeError(f"shell has {len(codes)} voxels < {n}")
    return np.sort(rng.choice(codes, n, replace=False))


def shell_radius(n: int) -> float:
    return min(0.98, 1.02 * np.sqrt(n / 2.99e6))


def sphere_view(cam: Camera, rng: np.random.Generator, r: float) -> FusionView:
    h, w = cam.height, cam.width
    yy, xx = np.mgrid[0:h, 0:w]
    d = cam.ray_directions(np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], -1))
    o = cam.center
    b = d @ o
    disc = b * b - (o @ o - r * r)
    t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), 0.0)
    hit = o + t[:, None] * d
    z = (t * (d @ cam.forward)).reshape(h, w).astype(np.float32)
    dmin = z * (1 - rng.uniform(0, 0.002, z.shape)).astype(np.float32)
    dmax = z * (1 + rng.uniform(0, 0.004, z.shape)).astype(np.float32)
    n = np.where(z > 0, rng.poisson(8, z.shape), 0).astype(np.float32)
    m = np.where((hit[:, 0] > 0).reshape(h, w) & (z > 0), 0.9, 0.1).astype(np.float32)
    return FusionView(cam, m, dmin, z, dmax, n, 3.0)


def make_views(r: float, k: int = 20, seed: int = 0) -> list[FusionView]:
    """20 views at distance 3 of a sphere of radius ``r`` (odd ones zoomed ×4 on a point
    of its equator, like centroid views)."""
    rng = np.random.default_rng(seed)
    views = []
    for i in range(k):
        a = 2 * np.pi * i / k
        eye = 3.0 * np.array([np.cos(a), np.sin(a), 0.3 * np.sin(3 * a)])
        f = 772.0 * (4 if i % 2 else 1)
        target = (
            0.6 * r * np.array([np.cos(a + 0.3), np.sin(a + 0.3), 0.0]) if i % 2 else np.zeros(3)
        )
        cam = Camera.look_at(eye, target, np.array([0, 0, 1.0]), width=640, height=480, fx=f)
        views.append(sphere_view(cam, rng, r))
    return views


def in_frame(centers: np.ndarray, views: list[FusionView]) -> int:
    """Σ over views of the voxels whose centre projects into the image."""
    tot = 0
    for v in views:
        uv, z = v.camera.project(centers)
        tot += int(
            (
                (z > 0)
                & (uv[:, 0] >= 0)
                & (uv[:, 0] < v.camera.width)
                & (uv[:, 1] >= 0)
                & (uv[:, 1] < v.camera.height)
            ).sum()
        )
    return tot


def timed(fn, repeats: int = 1) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        wp.synchronize()
        best = min(best, time.perf_counter() - t)
    return best


def bench_gs(sizes, ref_max, device) -> list[dict]:
    rows = []
    rng = np.random.default_rng(1)
    cfg = GsFusionConfig()
    geo = GridGeometry(np.zeros(3), B, H, G, 1.0, H / 3, False)
    for n in sizes:
        codes = shell_codes(rng, n)
        views = make_views(shell_radius(n))
        grid = OccupancyGrid.from_codes(geo, codes, np.ones(n), device=device)
        f = GsFusion(grid, cfg, device)
        f.add_view(views[0])  # warm-up (compile)
        f.reset()
        vd = f.upload(views[1])
        t_kernel = timed(lambda: f._launch(vd), 3)
        t_upload = timed(lambda: f.upload(views[1]), 3)

        def one_update():
            vid = f.add_view(views[1])
            wp.synchronize()
            return vid

        t_update = t_undo = np.inf
        for _ in range(3):
            t = time.perf_counter()
            vid = one_update()
            t_update = min(t_update, time.perf_counter() - t)
            t = time.perf_counter()
            f.remove_view(vid)
            wp.synchronize()
            t_undo = min(t_undo, time.perf_counter() - t)

        def refuse():
            f.reset()
            for i, v in enumerate(views):
                f.add_view(v, i)

        t_full = timed(refuse, 1)
        res = f.result()
        recs = len(f._records[1]) if 1 in f._records else 0
        stream = n * (12 + 9 + 40) + recs * 30
        row = dict(
            kind="2DGS",
            n=n,
            kernel=t_kernel,
            upload=t_upload,
            update=t_update,
            undo=t_undo,
            full=t_full,
            stream_gbs=stream / t_update / 1e9,
            ns_per_voxel=t_kernel / n * 1e9,
            thick=int(res.n_thick.sum()),
            thin=int(res.n_thin.sum()),
            seg=int(res.segmented.sum()),
            ref=None,
        )
        c = grid.centers()
        row["in_frame"] = in_frame(c, views)
        if n <= ref_max:
            d = np.ones(n)
            row["ref"] = timed(lambda: ref.gs_view(c, d, H, views[1], cfg), 1)
        rows.append(row)
        print_row(row)
    return rows


def bench_nerf(sizes, ref_max, device) -> list[dict]:
    """NeRF cells on the same shell (a sparse active list over a virtual 1024³ grid)."""
    rows = []
    rng = np.random.default_rng(2)
    cfg = nerf_preset("mip360")
    for n in sizes:
        codes = shell_codes(rng, n)
        views = make_views(shell_radius(n))
        from divas_engine.fusion.morton import morton_decode

        ijk = morton_decode(codes)
        lin = np.sort((ijk[:, 2] * G + ijk[:, 1]) * G + ijk[:, 0])
        cell = np.full(3, H)
        rep = NerfBuildReport((G, G, G), G**3, n, n / G**3, n, H, False, 0.0, 8 * n)
        occ = NerfOccupancy(
            wp.array(lin.astype(np.int32), dtype=wp.int32, device=device),
            wp.array(np.full(n, 100.0, np.float32), dtype=float, device=device),
            (G, G, G),
            np.array([[-B] * 3, [B] * 3]),
            cell,
            H,
            cfg,
            wp.get_device(device),
            rep,
        )
        f = NerfFusion(occ, cfg, device)
        f.add_view(views[0])
        f.reset()
        vd = f.upload(views[1])
        t_kernel = timed(lambda: f._launch(vd), 3)
        t_upload = timed(lambda: f.upload(views[1]), 3)
        t_update = timed(lambda: (f.add_view(views[1], 0), wp.synchronize()), 1)
        t_undo = timed(lambda: f.remove_view(0), 1)
        t_update = min(t_update, timed(lambda: (f.add_view(views[1], 0), wp.synchronize()), 1))
        f.remove_view(0)

        def refuse():
            f.reset()
            for v in views:
                f.add_view(v)

        t_full = timed(refuse, 1)
        res = f.result()
        c = occ.centers()
        row = dict(
            kind="NeRF",
            in_frame=in_frame(c, views),
            n=n,
            kernel=t_kernel,
            upload=t_upload,
            update=t_update,
            undo=t_undo,
            full=t_full,
            stream_gbs=n * (8 + 9 + 40) / t_update / 1e9,
            ns_per_voxel=t_kernel / n * 1e9,
            thick=int(res.n_thick.sum()),
            thin=int(res.n_thin.sum()),
            seg=int(res.segmented.sum()),
            ref=None,
        )
        if n <= ref_max:
            row["ref"] = timed(lambda: ref.nerf_view(c, np.full(n, 100.0), cell, views[1], cfg), 1)
        rows.append(row)
        print_row(row)
    return rows


def print_row(r: dict) -> None:
    refs = "—" if r["ref"] is None else f"{r['ref']:.2f}"
    sp = "—" if r["ref"] is None else f"{r['ref'] / r['kernel']:.0f}×"
    print(
        f"| {r['kind']} | {r['n']:,} | {r['upload'] * 1e3:.1f} | {r['kernel'] * 1e3:.1f} | "
        f"{r['update'] * 1e3:.1f} | "
        f"{r['undo'] * 1e3:.2f} | {r['full']:.2f} | {refs} | {sp} | {r['ns_per_voxel']:.0f} | "
        f"{r['in_frame'] / 1e6:.2f} | {r['full'] / r['in_frame'] * 1e9:.0f} | "
        f"{r['stream_gbs']:.2f} | {r['thick']:,}/{r['thin']:,} |",
        flush=True,
    )


def bench_build(counts, device) -> None:
    print("\n| surfels | g | active voxels | surfels/active | build s | peak MB | resident MB |")
    print("|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(3)
    for n in counts:
        p = rng.normal(size=(n, 3))
        p /= np.linalg.norm(p, axis=1, keepdims=True)
        p *= rng.choice([0.5, 0.75, 1.0], (n, 1))
        s = SurfelScene(
            p.astype(np.float32),
            np.tile([1, 0, 0, 0], (n, 1)).astype(np.float32),
            np.full((n, 2), 3e-4, np.float32),
            rng.uniform(0.2, 1, n).astype(np.float32),
            np.zeros((n, 1, 3), np.float32),
            0,
        )
        build_occupancy(s, GridConfig(), device)  # warm-up
        g = build_occupancy(s, GridConfig(), device)
        r = g.report
        print(
            f"| {n:,} | {r.g} | {r.n_active:,} | {r.surfels_per_active:.2f} | "
            f"{r.build_time_s:.2f} | {r.peak_bytes / 2**20:.0f} | {r.resident_bytes / 2**20:.1f} |",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100000,500000,2000000")
    ap.add_argument("--device", default=None)
    ap.add_argument("--ref-max", type=int, default=2_000_000)
    ap.add_argument("--nerf", action="store_true")
    ap.add_argument("--build", default="1000000,4000000")
    args = ap.parse_args()
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    sizes = [int(s) for s in args.sizes.split(",")]
    print(
        f"# fusion benchmark — {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, device {device}, {datetime.date.today()}, "
        f"warp {wp.__version__}, numpy {np.__version__}"
    )
    print(
        "\n| backend | active voxels | upload ms (SATs, π_dg) | kernel ms (1 view) | "
        "update ms (add 1 view, total) | undo ms | "
        "full re-fuse 20 views s | NumPy ref s (1 view) | speedup (kernel) | kernel ns/voxel | "
        "in-frame voxel·views (20 views, M) | full re-fuse ns per in-frame voxel·view | "
        "stream GB/s | thick/thin votes (20 views) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = bench_gs(sizes, args.ref_max, device)
    if args.nerf:
        rows += bench_nerf(sizes, args.ref_max, device)
    for kind in ("2DGS", "NeRF"):
        rr = [r for r in rows if r["kind"] == kind]
        if len(rr) > 1:
            a, b = rr[0], rr[-1]
            print(
                f"\n{kind} scaling {a['n']:,} → {b['n']:,} voxels (×{b['n'] / a['n']:.0f}): "
                f"kernel ×{b['kernel'] / a['kernel']:.1f}, "
                f"update ×{b['update'] / a['update']:.1f}, "
                f"full ×{b['full'] / a['full']:.1f}; in-frame voxel·views "
                f"×{b['in_frame'] / a['in_frame']:.1f}"
            )
    if args.build:
        bench_build([int(s) for s in args.build.split(",")], device)


if __name__ == "__main__":
    main()
