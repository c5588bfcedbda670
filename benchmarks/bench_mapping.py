"""Voxel-to-surfel mapping benchmark: time of one mapping update (Passes 1–3 with S
live views, after one new view was accepted) at 250k / 1M / 2M surfels and 1 / 5 / 20
views, against the NumPy reference of ``tests/mapping_reference.py``.

Scene: ``benchmarks/scenes.surfel_scene`` (a room plus four spheres, g_max = 1024).
Object: the four spheres — the fusion state is synthesised (no fusion run): a voxel is
segmented when its centre is within 2 h_v of a sphere surface, and carries the bit of
view s when it faces that camera. Views: 640×480, 60° FoV, 20 cameras at distance 4–6
around the spheres' centroid; mask M̃ = 0.9 where the pixel ray hits a sphere, 0.1
elsewhere.

    python benchmarks/bench_mapping.py [--sizes 250000,1000000,2000000] [--views 1,5,20]
                                       [--device cpu] [--ref-max-pairs 60000000]

Columns: ``update ms`` = ``SurfelMapper.map`` (early-outs on; includes the per-update
mask binarisation of the new view, the view-buffer upload and the host readback);
``full-count ms`` = the same without the exact early-outs (every 1σ box swept, as the
reference does); ``pass3 ms`` = its Pass-3 part; the NumPy reference is run when its
accepted (surfel, pixel) count is under ``--ref-max-pairs``.
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

from benchmarks.scenes import SPHERES, surfel_scene  # noqa: E402
from divas_engine.camera import Camera  # noqa: E402
from divas_engine.fusion import FusionResult, FusionView, GridConfig, build_occupancy  # noqa: E402
from divas_engine.mapping import MappingConfig, SurfelMapper  # noqa: E402
from tests.mapping_reference import map_reference  # noqa: E402

CENTERS = np.array([c for c, _ in SPHERES])
RADII = np.array([r for _, r in SPHERES])
TARGET = CENTERS.mean(0)


def make_cameras(k: int, seed: int = 0) -> list[Camera]:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(k):
        d = rng.normal(size=3)
        d[2] = -abs(d[2]) - 0.3  # mostly from the camera side of the room (z < target)
        d /= np.linalg.norm(d)
        eye = TARGET + rng.uniform(4.0, 6.0) * d
        cams.append(
            Camera.look_at(
                eye,
                TARGET,
                np.array([0, -1.0, 0]),
                width=640,
                height=480,
                fx=640 / (2 * np.tan(np.radians(30))),
                name=f"v{i}",
            )
        )
    return cams


def sphere_mask(cam: Camera) -> np.ndarray:
    h, w = cam.height, cam.width
    yy, xx = np.mgrid[0:h, 0:w]
    d = cam.ray_directions(np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], -1))
    o = cam.center
    hit = np.zeros(len(d), bool)
    for c, r in zip(CENTERS, RADII):
        oc = o - c
        b = d @ oc
        disc = b * b - (oc @ oc - r * r)
        hit |= (disc > 0) & (-b + np.sqrt(np.maximum(disc, 0)) > 0)
    return np.where(hit, 0.9, 0.1).astype(np.float32).reshape(h, w)


def synth_fusion(grid, cams: list[Camera]) -> FusionResult:
    cen = grid.centers()
    h = grid.geometry.voxel_size
    dist = np.linalg.norm(cen[:, None, :] - CENTERS[None], axis=2) - RADII[None]
    near = np.abs(dist) < 2 * h
    seg = near.any(1)
    which = np.argmin(np.abs(dist), axis=1)
    nrm = cen - CENTERS[which]
    a = len(cen)
    vm = np.zeros((a, 2), np.uint32)
    for s, cam in enumerate(cams):
        facing = np.einsum("ij,ij->i", nrm, cam.center - cen) > 0
        vm[:, s // 32] |= np.where(seg & facing, np.uint32(1 << (s % 32)), np.uint32(0))
    z = np.zeros(a)
    return FusionResult(
        P=seg.astype(float),
        segmented=seg,
        vmask=vm,
        vmask_raw=vm,
        W=z,
        Z=z,
        W_thin=z,
        n_thick=np.zeros(a, np.int32),
        n_thin=np.zeros(a, np.int32),
    )


def view(cam: Camera, mask: np.ndarray) -> FusionView:
    z = np.zeros((cam.height, cam.width), np.float32)
    return FusionView(cam, mask, z, z, z, z, 1.0, cam.name)


def timed_update(mapper, fused, views, cfg, reps: int) -> tuple[float, dict]:
    """Median ``map`` time with the last view freshly accepted (new to the view cache)."""
    ts, secs = [], None
    for _ in range(reps):
        last = views[-1]
        fresh = view(last.camera, last.mask)  # a new view object: binarised + uploaded anew
        vs = views[:-1] + [fresh]
        if len(views) > 1:
            mapper.map(fused, views[:-1], list(range(len(views) - 1)), cfg)
        t = time.perf_counter()
        r = mapper.map(fused, vs, list(range(len(vs))), cfg)
        ts.append(time.perf_counter() - t)
        secs = r.seconds
    return float(np.median(ts)), {"res": r, "seconds": secs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="250000,1000000,2000000")
    ap.add_argument("--views", default="1,5,20")
    ap.add_argument("--device", default=None)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--ref-max-pairs", type=float, default=6e7)
    args = ap.parse_args()
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    vcounts = [int(v) for v in args.views.split(",")]
    cams = make_cameras(max(vcounts))
    masks = [sphere_mask(c) for c in cams]
    all_views = [view(c, m) for c, m in zip(cams, masks)]
    print(
        f"# mapping benchmark — {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, device {device}, {datetime.date.today()}, "
        f"warp {wp.__version__}, numpy {np.__version__}"
    )
    print(
        "\n| surfels | views | f¹ | f² | f | scored surfel·views | accepted pixels (M) | "
        "update ms | pass1 / pass2 / views / pass3 / readback ms | full-count ms | "
        "NumPy ref s | speedup (update) | speedup (full-count) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in [int(s) for s in args.sizes.split(",")]:
        scene = surfel_scene(n, sh_degree=0)
        grid = build_occupancy(scene, GridConfig(), device=device)
        fused = synth_fusion(grid, cams)
        mapper = SurfelMapper(scene, grid, device=device)
        mapper.map(fused, all_views[:1], [0])  # compile / warm
        for k in vcounts:
            vs = all_views[:k]
            t_up, info = timed_update(mapper, fused, vs, MappingConfig(), args.reps)
            r, sec = info["res"], info["seconds"]
            t_full, _ = timed_update(mapper, fused, vs, MappingConfig(early_out=False), args.reps)
            px = sum(int(mapper.view_counts(fused, v, s)[0].sum()) for s, v in enumerate(vs))
            ref_s = sp_up = sp_full = "—"
            if px < args.ref_max_pairs:
                t = time.perf_counter()
                ref = map_reference(
                    scene,
                    grid.geometry,
                    grid.codes.numpy(),
                    fused.segmented,
                    fused.vmask,
                    vs,
                    list(range(k)),
                )
                ref_t = time.perf_counter() - t
                ok = ~ref["ambiguous"]
                assert np.array_equal(ref["selected"][ok], r.selected[ok])
                ref_s = f"{ref_t:.2f}"
                sp_up = f"{ref_t / t_up:.0f}×"
                sp_full = f"{ref_t / t_full:.0f}×"
            print(
                f"| {n:,} | {k} | {r.n_pass1:,} | {r.n_pass2:,} | {r.n_selected:,} | "
                f"{r.n_scored:,} | {px / 1e6:.2f} | {t_up * 1e3:.1f} | "
                f"{sec['pass1'] * 1e3:.1f} / {sec['pass2'] * 1e3:.1f} / {sec['views'] * 1e3:.1f} / "
                f"{sec['pass3'] * 1e3:.1f} / {sec['readback'] * 1e3:.1f} | "
                f"{t_full * 1e3:.1f} | {ref_s} | {sp_up} | {sp_full} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
