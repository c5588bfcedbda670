"""Per-update cost: DivAS's incremental fusion + mapping vs a FlashSplat-style
re-accumulation over every fused view, side by side in one run.

Each update adds one accepted view. DivAS runs the new view's fusion kernel (sparse,
exactly undoable record) and re-maps voxels to surfels (``GsFusion.add_view`` +
``fusion.result()`` + ``SurfelMapper.map`` — what ``Session.accept`` runs). The
FlashSplat-style baseline (contribution-weighted voting, ``evaluation.baselines``) has
no incremental state: after each update it re-accumulates A₁/A₀ over *all* fused views
(one blending pass per view) and thresholds. Its cost at ``k`` views is measured as one
real re-accumulation over ``max(views)`` views, timed per pass: the update at ``k`` costs
the first ``k`` passes plus the vote.

Views: the scene's training cameras that see the target, at ≤ 640 px wide; masks are the
ground truth rendered into each view (``render_values ≥ 0.5``: a perfect segmenter), so
the two methods do the same job on the same inputs.

    python benchmarks/bench_fusion_vs_flashsplat.py [--sizes 250000,1000000] [--views 5,10,20]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from divas_engine.evaluation.baselines import ContributionVoter, MaskView
from divas_engine.fusion import FusionView, GridConfig, GsFusion, build_occupancy
from divas_engine.io.cameras import load_cameras
from divas_engine.io.load import load_scene
from divas_engine.mapping import MappingConfig, SurfelMapper
from divas_engine.render import make_renderer


def _views(scene, cameras, labels, renderer, n_views: int):
    target = scene.means[labels > 0.5].mean(0)
    out = []
    for cam in cameras:
        if cam.width > 640:
            cam = cam.scaled(640 / cam.width)
        uv, z = cam.project(target[None])
        if not (z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height):
            continue
        b = renderer.render(cam)
        m = (renderer.render_values(cam, labels) >= 0.5).astype(np.float32)
        if m.sum() < 50:
            continue
        d_cam = float(np.linalg.norm(cam.center - target))
        out.append((cam, m, b, d_cam))
        if len(out) == n_views:
            break
    return out


def measure(folder, views_at: list[int], device: str = "cpu") -> dict:
    from bench_session import sync

    scene = load_scene(folder / "scene.ply")
    cameras = load_cameras(folder / "cameras.json")
    labels = np.load(folder / "labels.npy").astype(np.float32)
    renderer = make_renderer(scene, device=device)
    vmax = max(views_at)
    views = _views(scene, cameras, labels, renderer, vmax)
    if len(views) < vmax:
        raise SystemExit(f"only {len(views)} training cameras see the target (need {vmax})")
    # DivAS: incremental
    grid = build_occupancy(scene, GridConfig(), device)
    fusion = GsFusion(grid)
    mapper = SurfelMapper(scene, grid, MappingConfig(), device)
    live, slots, divas = [], [], []
    for k, (cam, m, b, d_cam) in enumerate(views):
        fv = FusionView(cam, m, b.D_min, b.D_ref, b.D_max, b.N_samp, d_cam, f"v{k}")
        t = time.perf_counter()
        slots.append(fusion.add_view(fv))
        live.append(fv)
        res = mapper.map(fusion.result(), live, slots)
        sync(device)
        divas.append(time.perf_counter() - t)
    # FlashSplat-style: re-accumulate over all fused views at every update
    voter = ContributionVoter(scene, device)
    a1 = np.zeros(len(scene))
    a0 = np.zeros(len(scene))
    passes = []
    for cam, m, _, _ in views:
        t = time.perf_counter()
        p, q = voter.contributions(MaskView(cam, m))
        a1 += p
        a0 += q
        sync(device)
        passes.append(time.perf_counter() - t)
    t = time.perf_counter()
    fs_sel = a1 > a0
    vote_s = time.perf_counter() - t
    return {
        "n": len(scene),
        "active": len(grid),
        "divas": divas,
        "fs": [sum(passes[:k]) + vote_s for k in range(1, vmax + 1)],
        "selected": (int(res.selected.sum()), int(fs_sel.sum())),
    }


def print_fusion_vs_reaccumulation(
    scene: str, sizes: list[int], views_at: list[int], files, device: str = "cpu"
):
    print(
        f"\n## Per-update cost: incremental fusion vs FlashSplat-style re-accumulation "
        f"({scene}, {device})\n"
    )
    print(
        "| surfels | active voxels | fused views | DivAS update ms | re-accumulation ms | ratio |"
    )
    print("|---:|---:|---:|---:|---:|---:|")
    for n in sizes:
        r = measure(files(scene, n), views_at, device)
        for k in views_at:
            d, f = r["divas"][k - 1] * 1e3, r["fs"][k - 1] * 1e3
            print(f"| {r['n']:,} | {r['active']:,} | {k} | {d:.0f} | {f:.0f} | {f / d:.1f}× |")
        print(
            f"| | | (selected after {max(views_at)}: DivAS {r['selected'][0]:,}, "
            f"vote {r['selected'][1]:,}) | | | |"
        )


if __name__ == "__main__":
    from bench_session import scene_files

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="plant")
    ap.add_argument("--sizes", default="250000,1000000")
    ap.add_argument("--views", default="5,10,20")
    a = ap.parse_args()
    print_fusion_vs_reaccumulation(
        a.scene, [int(s) for s in a.sizes.split(",")], [int(v) for v in a.views.split(",")],
        scene_files,
    )  # fmt: skip
