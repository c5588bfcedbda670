"""Per-update cost of the 3DGS completion at 250k / 1M Gaussians.

Scene: ``benchmarks/scenes.surfel_scene`` marked 3DGS, the fusion state synthesised as in
``bench_mapping.py``; views 640×480, masks = the spheres' silhouettes. Columns:

* ``view records ms`` — :meth:`VolumetricCompletion.view_record` (contribution gather plus
  voxel projection); ``of which gather ms``; ``gather, binning kept ms`` with the view's
  binning kept by the renderer;
* ``sparse gather ms`` — the gather restricted to the cover of the selection's neighbourhood
  (``cover`` / ``sub-scene`` sizes, ``mask %``, ``equal`` against the full pass);
* ``kept gather ms`` — the records from the kept binning's tile lists (``walked`` pairs);
* ``accept ms`` — the whole update with the sparse gather (``add_view`` + ``complete``);
  ``kept accept ms`` / ``kept accept CPU ms`` from the kept binning (what the user waits for);
* ``add ms`` / ``undo ms`` — adding / subtracting a view's integer records;
* ``decide ms`` — :meth:`VolumetricCompletion.complete` with S live views.

``render ms`` is one plain render of the same view, for scale.

    python benchmarks/bench_completion.py [--sizes 250000,1000000] [--views 1,5,20]
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import bench_mapping  # noqa: E402
from benchmarks.bench_mapping import make_cameras, sphere_mask, synth_fusion  # noqa: E402
from benchmarks.scenes import surfel_scene  # noqa: E402
from divas_engine.fusion import FusionView, GridConfig, build_occupancy  # noqa: E402
from divas_engine.kinds import SceneKind  # noqa: E402
from divas_engine.mapping import CompletionConfig, SurfelMapper  # noqa: E402
from divas_engine.mapping.completion import VolumetricCompletion  # noqa: E402
from divas_engine.render import make_renderer  # noqa: E402

ALL_CENTERS, ALL_RADII = bench_mapping.CENTERS, bench_mapping.RADII


def median_ms(fn, reps: int, cpu: list | None = None) -> float:
    """Median wall ms of ``fn``; with ``cpu`` (a list) also appends the median process CPU
    ms (all threads; less sensitive than the wall time to other processes' load)."""
    ts, cs = [], []
    for _ in range(reps):
        c = time.process_time()
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    if cpu is not None:
        cpu.append(1e3 * float(np.median(cs)))
    return 1e3 * float(np.median(ts))


def run(n: int, view_counts: list[int], reps: int, device: str, spheres: str = "") -> list[dict]:
    if spheres:  # the object: these spheres only (their masks and voxel selection)
        k = [int(x) for x in spheres.split(",")]
        bench_mapping.CENTERS, bench_mapping.RADII = ALL_CENTERS[k], ALL_RADII[k]
    scene = surfel_scene(n, sh_degree=0)
    scene.kind = SceneKind.GS3D
    scene.scale_n = np.full(n, 1e-3, np.float32)
    grid = build_occupancy(scene, GridConfig(), device)
    mapper = SurfelMapper(scene, grid, device=device)
    cams = make_cameras(max(view_counts))
    fused = synth_fusion(grid, cams)
    renderer = make_renderer(scene, device=device)
    views = []
    for cam in cams:
        b = renderer.render(cam)
        views.append(
            FusionView(cam, sphere_mask(cam), b.D_min, b.D_med, b.D_max, b.N_samp, 5.0, cam.name)
        )
    t = time.perf_counter()
    comp = VolumetricCompletion(scene, grid, mapper.active_index, CompletionConfig(), device=device)
    setup_s = time.perf_counter() - t
    sel = np.zeros(n, bool)
    act = mapper.active_index
    sel[act >= 0] = fused.segmented[act[act >= 0]]
    rows = []
    render_ms = median_ms(lambda: renderer.render(cams[0]), reps)
    rec_ms = median_ms(lambda: comp.view_record(views[0]), reps)
    cam = cams[0]
    pos = views[0].mask >= 0.5
    # the gather alone (a renderer that kept no binning of this view: a full rasterizer
    # pass), then the same gather once the accept's render kept the view's binning (only
    # the tile walk runs; :meth:`SurfelRenderer.contributions`)
    fresh = make_renderer(scene, device=device)
    gather_ms = median_ms(lambda: fresh.contributions(cam, pos), reps)
    renderer.render(cam)
    assert renderer.kept_binning(cam) is not None
    gather_kept_ms = median_ms(
        lambda: renderer.contributions(cam, pos),
        reps,
    )
    sp = VolumetricCompletion(scene, grid, mapper.active_index, CompletionConfig(), device=device)
    sp.add_view(0, views[0])
    sp.complete(sel, fused.segmented)
    rec0 = sp._records[0][1]
    cover = rec0.cover
    pos0, rho0 = sp._mask(views[0])
    sparse_ms = median_ms(lambda: sp._gauss_record(views[0], cover, pos0, rho0), reps)
    # the session's case: the completion shares the renderer, the view was just rendered
    kp = VolumetricCompletion(
        scene, grid, mapper.active_index, CompletionConfig(), device=device, renderer=renderer
    )
    assert kp._renderer is renderer
    renderer.render(cam)
    kp.add_view(0, views[0])
    kp.complete(sel, fused.segmented)
    kept_ms = median_ms(lambda: kp._gauss_record(views[0], cover, pos0, rho0), reps)
    from divas_kernels import accumulate_contributions

    walked = accumulate_contributions(
        renderer.surfel_buffers,
        cam.w2c, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
        pos,
        renderer.config.raster_settings(cam),
        binning=renderer.kept_binning(cam),
        targets=np.sort(sp.cells.members(cover)),
    ).stats["walked"]  # fmt: skip
    full0 = comp.view_record(views[0])
    covered = np.zeros(n, bool)
    covered[sp.cells.members(cover) if cover is not None else slice(None)] = True
    keep = covered[full0.gauss]
    o = np.argsort(rec0.gauss)
    equal = all(
        np.array_equal(getattr(full0, f)[keep], getattr(rec0, f)[o])
        for f in ("gauss", "q1", "q0", "seen", "deep")
    )
    vcov = np.ones(len(grid), bool)
    if cover is not None:
        vcov[:] = False
        vcov[sp.cells.voxels_in(np.flatnonzero(cover))] = True
    vk, vo = vcov[full0.voxels], np.argsort(rec0.voxels)
    equal &= np.array_equal(full0.voxels[vk], rec0.voxels[vo])
    equal &= np.array_equal(full0.flags[vk], rec0.flags[vo])
    rk = kp._records[0][1]
    ko = np.argsort(rk.gauss)
    kc = np.zeros(n, bool)
    kc[kp.cells.members(rk.cover) if rk.cover is not None else slice(None)] = True
    equal &= all(
        np.array_equal(getattr(full0, f)[kc[full0.gauss]], getattr(rk, f)[ko])
        for f in ("gauss", "q1", "q0", "seen", "deep")
    )
    from divas_engine.mapping.completion_gather import sparse_contributions

    sub = sparse_contributions(sp._renderer, cam, pos, sp.cells.members(cover), 1.0)[2]

    def accept() -> None:
        sp.remove_view(0)
        sp.add_view(0, views[0])
        sp.complete(sel, fused.segmented)

    accept_ms = median_ms(accept, reps)

    def kept_accept() -> None:
        kp.remove_view(0)
        kp.add_view(0, views[0])
        kp.complete(sel, fused.segmented)

    kept_cpu: list[float] = []
    kept_accept_ms = median_ms(kept_accept, reps, kept_cpu)
    for s in view_counts:
        for k in list(comp.keys):
            comp.remove_view(k)
        for i in range(s - 1):
            comp.add_view(i, views[i])
        rec = comp.view_record(views[s - 1])

        adds, undos = [], []
        for _ in range(reps):
            t = time.perf_counter()
            comp._apply(rec, +1)
            adds.append(time.perf_counter() - t)
            t = time.perf_counter()
            comp._apply(rec, -1)
            undos.append(time.perf_counter() - t)
        add_ms, undo_ms = 1e3 * float(np.median(adds)), 1e3 * float(np.median(undos))
        comp.add_view(s - 1, views[s - 1])
        comp.complete(sel, fused.segmented)  # gathers the new records: decide alone below
        decide = median_ms(lambda: comp.complete(sel, fused.segmented), reps)
        res = comp.complete(sel, fused.segmented)
        rows.append(
            {
                "gaussians": n,
                "views": s,
                "active_voxels": len(grid),
                "coarse_cells": comp.cells.n,
                "setup_s": setup_s,
                "render_ms": render_ms,
                "record_ms": rec_ms,
                "gather_ms": gather_ms,
                "gather_kept_ms": gather_kept_ms,
                "sparse_gather_ms": sparse_ms,
                "kept_gather_ms": kept_ms,
                "walked": int(walked),
                "kept_accept_ms": kept_accept_ms,
                "kept_accept_cpu_ms": kept_cpu[0],
                "cover": int(covered.sum()),
                "sub_scene": int(sub),
                "mask_share": float(pos.mean()),
                "equal": bool(equal),
                "accept_ms": accept_ms,
                "add_ms": add_ms,
                "undo_ms": undo_ms,
                "decide_ms": decide,
                "added": int(res.contrib_added.sum() + res.fill_added.sum()),
            }
        )
        r = rows[-1]
        print(
            f"| {n:,} | {s} | {r['active_voxels']:,} | {r['render_ms']:.0f} | "
            f"{r['record_ms']:.0f} | {r['gather_ms']:.0f} | {r['gather_kept_ms']:.0f} | "
            f"{r['sparse_gather_ms']:.0f} | {r['kept_gather_ms']:.0f} | {r['walked']:,} | "
            f"{r['cover']:,} | {r['sub_scene']:,} | "
            f"{100 * r['mask_share']:.1f} | {r['equal']} | {r['accept_ms']:.0f} | "
            f"{r['kept_accept_ms']:.0f} | {r['kept_accept_cpu_ms']:.0f} | "
            f"{r['add_ms']:.1f} | "
            f"{r['undo_ms']:.1f} | {r['decide_ms']:.1f} | {r['setup_s']:.2f} |",
            flush=True,
        )
    return rows


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="250000,1000000")
    p.add_argument("--views", default="1,5,20")
    p.add_argument("--reps", type=int, default=5)
    p.add_argument("--device", default="cpu")
    p.add_argument("--spheres", default="", help="the object's spheres, e.g. 0 (default all)")
    a = p.parse_args()
    cpu = platform.processor() or platform.machine()
    print(f"# bench_completion {datetime.date.today()} {cpu} ({os.cpu_count()} CPUs), {a.device}")
    print(
        "| Gaussians | views | active voxels | render ms | view records ms | of which gather "
        "ms | gather, binning kept ms | sparse gather ms | kept gather ms | walked | cover | "
        "sub-scene | mask % | equal | accept ms | kept accept ms | kept accept CPU ms | "
        "add ms | undo ms | "
        "decide ms | setup s |"
    )
    print("|" + "---:|" * 21)
    for n in (int(x) for x in a.sizes.split(",")):
        run(n, [int(x) for x in a.views.split(",")], a.reps, a.device, a.spheres)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
