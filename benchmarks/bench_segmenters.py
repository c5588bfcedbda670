"""ClassicSegmenter vs plain flood fill on the synthetic scenes' centroid views; and with
``--cost``, the cost per prompt of the default 3D graph segmenter at up to 1M
surfels beside classic's on the same view.

Per synthetic scene: each metadata click on the target is projected into its best unoccluded
training camera (the anchor), its 2DGS centroid view (alg:centroid-gs) is rendered and both
segmenters get the click's 3D point as the one positive prompt; 2D IoU of mask channel 1
(p ≥ 0.5) against ``render_values(cam, labels) ≥ 0.5`` (NOTES "Evaluation").

    .venv/bin/python benchmarks/bench_segmenters.py [--size 100000] [--seed 0] [--clicks 4]
    .venv/bin/python benchmarks/bench_segmenters.py --cost [--sizes 100000,1000000]
        [--walk-solver jacobi_cg]

``--cost``: the benchmark room of :mod:`benchmarks.scenes` at each size, one click per sphere
(fresh seeds, so no cut is cached); per prompt the 3D cut and the render of its regions at
SAM's low-res size, classic's ``set_image`` + ``predict`` on the same view for the ratio, and
the prompt's CPU time (``process_time``, all threads). The one-time per-scene preparation is
reported apart.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.scenes import SPHERES, bench_camera, surfel_scene  # noqa: E402
from divas_engine.render.surfel_renderer import SurfelRenderer  # noqa: E402
from divas_engine.segment import ClassicSegmenter, FloodFillSegmenter  # noqa: E402
from divas_engine.synthetic import SCENE_NAMES, generate_scene  # noqa: E402
from divas_engine.views import GsCentroidPlanner  # noqa: E402


def best_anchor(s, r, click, max_candidates: int = 8):
    cams = {c.name: c for c in s.cameras}
    names = click["visible_in"]
    pick = np.unique(
        np.linspace(0, len(names) - 1, min(max_candidates, len(names))).round().astype(int)
    )
    x = np.array([click["xyz"]])
    best = None
    for i in pick:
        cam = cams[names[i]]
        uv, z = cam.project(x)
        u, v = uv[0]
        if not (0 <= u < cam.width and 0 <= v < cam.height) or z[0] <= 0:
            continue
        buf = r.render(cam)
        d = float(buf.D_med[int(v), int(u)])
        if abs(d - z[0]) > 0.03 * z[0] or buf.alpha[int(v), int(u)] < 0.5:
            continue
        if best is None or z[0] < best[3]:
            best = (cam, buf, (float(u), float(v)), float(z[0]))
    return best


def iou(a: np.ndarray, b: np.ndarray) -> float:
    u = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / u) if u else float("nan")


def cost(sizes: list[int], walk_solver: str | None = None) -> None:
    """Per-prompt cost of the graph3d segmenter vs classic (module docstring);
    ``walk_solver``: a :class:`~divas_engine.segment.graph3d.config.WalkSolver` value."""
    from divas_engine.segment import Graph3DSegmenter, SceneBinding
    from divas_engine.segment.graph3d import Seeds
    from divas_engine.segment.graph3d.config import Graph3DConfig

    cfg = Graph3DConfig() if walk_solver is None else Graph3DConfig(walk_solver=walk_solver)

    cam = bench_camera()
    print(
        "| surfels | prepare s (once) | cut ms | render ms | graph3d prompt ms | voxels | "
        "classic prompt ms | ratio | graph3d prompt CPU ms (cut + render) |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n in sizes:
        scene = surfel_scene(n)
        r = SurfelRenderer(scene, device="cpu")
        sparse = r.render_values_sparse
        bind = SceneBinding(scene, r.render_values, render_sparse=sparse)
        seg = Graph3DSegmenter(cfg, binding=bind)
        t = time.perf_counter()
        seg.primitives()
        r.sparse_index()  # the renderer's block index: once per scene, like the features
        prep = time.perf_counter() - t
        view = r.render(cam)
        cuts, renders, vox, classic, cpu = [], [], [], [], []
        for cen, rad in SPHERES:
            c = np.asarray(cen, float)
            p = c - np.array([0.0, 0.0, rad])  # the sphere's point facing the camera
            t, c0 = time.perf_counter(), time.process_time()
            rc = seg.cut(Seeds(p[None], np.zeros((0, 3))))
            t1, c1 = time.perf_counter(), time.process_time()
            seg.render_masks(cam, rc.selected)
            t2, c2 = time.perf_counter(), time.process_time()
            cpu.append((c1 - c0, c2 - c1))
            cuts.append(t1 - t)
            renders.append(t2 - t1)
            vox.append(rc.info.get("voxels", 0))
            uv = cam.project(p[None])[0]
            cl = ClassicSegmenter()
            t = time.perf_counter()
            cl.set_image(view.rgb, view.D_med)
            cl.predict(uv, np.array([1]))
            classic.append(time.perf_counter() - t)
        g = 1000 * (np.median(cuts) + np.median(renders))
        c = 1000 * np.median(classic)
        print(
            f"| {n:,} | {prep:.1f} | {1000 * np.median(cuts):.0f} | "
            f"{1000 * np.median(renders):.0f} | {g:.0f} | {int(np.median(vox)):,} | "
            f"{c:.0f} | {g / c:.2f} | {1000 * np.median(np.sum(cpu, axis=1)):.0f} "
            f"({1000 * np.median([x[0] for x in cpu]):.0f} + "
            f"{1000 * np.median([x[1] for x in cpu]):.0f}) |",
            flush=True,
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cost", action="store_true", help="graph3d cost per prompt")
    ap.add_argument("--sizes", default="100000,1000000", help="surfel counts for --cost")
    ap.add_argument("--walk-solver", default=None, help="--cost: two_level (default), jacobi_cg")
    ap.add_argument("--size", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--clicks", type=int, default=4)
    ap.add_argument("--scenes", nargs="*", default=list(SCENE_NAMES))
    a = ap.parse_args(argv)
    if a.cost:
        cost([int(x) for x in a.sizes.split(",")], a.walk_solver)
        return 0
    rows = []
    t0 = time.perf_counter()
    for name in a.scenes:
        s = generate_scene(name, None, size=a.size, seed=a.seed)
        r = SurfelRenderer(s.scene, device="cpu")
        planner = GsCentroidPlanner(s.scene, r)
        labels = s.labels.astype(np.float32)
        part_of = np.array([sf["part"] for sf in s.metadata["surfaces"]] + ["<floater>"])
        surfel_part = part_of[s.surface_ids]  # surface_ids == -1 → floater (last entry)
        for k, click in enumerate(s.metadata["clicks"][: a.clicks]):
            best = best_anchor(s, r, click)
            if best is None:
                rows.append((name, f"{k}:{click['part']}", None, None, "no unoccluded anchor", 0.0))
                continue
            anchor, buf, uv, _ = best
            cv = planner.centroid_view(anchor, uv, buf, name=f"{name}_c{k}")
            view = r.render(cv.camera)
            gt = r.render_values(cv.camera, labels) >= 0.5
            part = (surfel_part == click["part"]).astype(np.float32)
            gt_part = r.render_values(cv.camera, part) >= 0.5
            prompt = cv.camera.project(cv.target[None])[0]
            res = []
            for seg in (ClassicSegmenter(), FloodFillSegmenter()):
                seg.set_image(view.rgb, view.D_med)
                masks, _ = seg.predict(prompt, np.array([1]))
                res.append((iou(masks[1] >= 0.5, gt), iou(masks[1] >= 0.5, gt_part)))
            fill = float(gt.mean())
            rows.append(
                (name, f"{k}:{click['part']} ({anchor.name})", res[0], res[1], cv.strategy, fill)
            )
    print(f"synthetic scenes, size {a.size}, seed {a.seed}; {time.perf_counter() - t0:.0f} s\n")
    print("IoU vs the whole target object / vs the clicked part (a single click asks for a part)\n")
    print(
        "| scene | view (click:part (anchor)) | centroid strategy | GT fill | classic (object) | "
        "flood fill (object) | classic (part) | flood fill (part) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for n, v, c, f, st, fill in rows:
        if c is None:
            print(f"| {n} | {v} | {st} | — | — | — | — | — |")
            continue
        print(
            f"| {n} | {v} | {st} | {fill:.2f} | {c[0]:.3f} | {f[0]:.3f} | {c[1]:.3f} | {f[1]:.3f} |"
        )
    for n in a.scenes + ["all"]:
        sel = [r_ for r_ in rows if (n == "all" or r_[0] == n) and r_[2] is not None]
        if sel:
            m = [np.nanmean([x[i][j] for x in sel]) for i, j in ((2, 0), (3, 0), (2, 1), (3, 1))]
            print(
                f"| {n} | **mean** ({len(sel)} views) | | | "
                + " | ".join(f"{v:.3f}" for v in m)
                + " |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
