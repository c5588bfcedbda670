"""Rendering benchmark (not a test): Warp renderers vs the NumPy references.

Cases: synthetic surfel scenes (``benchmarks/scenes.py``: a room around the camera
plus four spheres, SH degree 3, ~half the surfels outside the view) of 250k and 1M
surfels at 640×480 and 1280×960, and a 256³ density grid at 640×480.

Warp time: median of ``--repeats`` warm renders (compilation and the first render
excluded; includes the copy of every buffer back to NumPy). NumPy time: the
references of ``tests/reference_render.py`` — the same algorithm vectorised over
(surfel, pixel) pairs for 2DGS and over rays for NeRF — timed on a band of
``--ref-rows`` image rows and extrapolated linearly to the full image (the
pair/ray work is proportional to rows for these scenes). The band's buffers are
also compared with the Warp render (``agree`` = fraction of band pixels equal
within RGB 1e-3, depth 1e-4 rel., N_samp exact).

    python benchmarks/bench_render.py [--repeats 5] [--ref-rows 48] [--quick]
"""

from __future__ import annotations

import argparse
import datetime
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.scenes import bench_camera, density_grid, surfel_scene  # noqa: E402
from divas_engine.render import RenderConfig, make_renderer  # noqa: E402
from tests.reference_render import reference_nerf, reference_surfels_pairs  # noqa: E402


def _machine() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        model = next(
            ln.split(":", 1)[1].strip() for ln in out.splitlines() if ln.startswith("Model name")
        )
    except (OSError, subprocess.CalledProcessError, StopIteration):
        model = platform.processor() or "unknown CPU"
    import os

    return f"{model}, {len(os.sched_getaffinity(0))} cores"


def _time(fn, repeats: int) -> tuple[float, object]:
    out = fn()  # warm-up (compile on first use)
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), out


def _agree(b, ref, rows: tuple[int, int]) -> float:
    y0, y1 = rows
    sl = slice(y0, y1)
    ok = np.abs(b.rgb[sl] - ref["feat"]).max(-1) < 1e-3
    for k in ("D_min", "D_med", "D_max", "D_mw", "D_exp"):
        e = ref[k]
        ok &= np.abs(getattr(b, k)[sl] - e) <= 1e-4 * np.maximum(np.abs(e), 1e-6)
    ok &= b.N_samp[sl] == ref["N_samp"]
    return float(ok.mean())


def bench_surfels(n: int, width: int, repeats: int, ref_rows: int, scene_cache: dict) -> dict:
    if n not in scene_cache:
        scene_cache[n] = surfel_scene(n)
    scene = scene_cache[n]
    cam = bench_camera(width, width * 3 // 4)
    r = make_renderer(scene, "cpu", RenderConfig())
    t_warp, b = _time(lambda: r.render(cam), repeats)
    y0 = cam.height // 2 - ref_rows // 2
    rows = (y0, y0 + ref_rows)
    t = time.perf_counter()
    ref = reference_surfels_pairs(scene, cam, rows=rows)
    t_ref = (time.perf_counter() - t) * cam.height / ref_rows
    return {
        "case": f"2DGS {n // 1000}k surfels",
        "res": f"{cam.width}×{cam.height}",
        "warp": t_warp,
        "ref": t_ref,
        "agree": _agree(b, ref, rows),
        "trav": float(ref["n_trav"].mean()),
        "visible": b.stats.get("visible", 0),
        "pairs": b.stats.get("pairs", 0),
    }


def bench_nerf(res: int, width: int, repeats: int, ref_rows: int) -> dict:
    grid = density_grid(res)
    cam = bench_camera(width, width * 3 // 4)
    r = make_renderer(grid, "cpu", RenderConfig())
    t_warp, b = _time(lambda: r.render(cam), repeats)
    y0 = cam.height // 2 - ref_rows // 2
    rows = (y0, y0 + ref_rows)
    t = time.perf_counter()
    ref = reference_nerf(grid, cam, rows=rows)
    t_ref = (time.perf_counter() - t) * cam.height / ref_rows
    return {
        "case": f"NeRF {res}³ grid",
        "res": f"{cam.width}×{cam.height}",
        "warp": t_warp,
        "ref": t_ref,
        "agree": _agree(b, ref, rows),
        "trav": float(b.N_samp.mean()),
        "visible": int((grid.density > 0).sum()),
        "pairs": 0,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-rows", type=int, default=48)
    ap.add_argument("--quick", action="store_true", help="250k / 640×480 / 128³ only")
    a = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    cache: dict = {}
    rows = []
    sizes = (
        [(250_000, 640)]
        if a.quick
        else [(250_000, 640), (250_000, 1280), (1_000_000, 640), (1_000_000, 1280)]
    )
    for n, w in sizes:
        rows.append(bench_surfels(n, w, a.repeats, a.ref_rows, cache))
        print(f"  done: {rows[-1]['case']} {rows[-1]['res']}", file=sys.stderr)
    rows.append(bench_nerf(128 if a.quick else 256, 640, a.repeats, min(a.ref_rows, 24)))
    print(
        f"\nMachine: {_machine()}; Warp {wp.__version__} on `cpu`; "
        f"{datetime.date.today().isoformat()}\n"
    )
    print(
        "| case | image | Warp CPU (s) | NumPy ref (s, extrapolated) | speed-up | agree | "
        "mean per pixel |"
    )
    print("|---|---|---:|---:|---:|---:|---|")
    for r in rows:
        per = (
            f"{r['trav']:.1f} surfels traversed"
            if r["case"].startswith("2DGS")
            else f"N_samp {r['trav']:.1f}"
        )
        print(
            f"| {r['case']} | {r['res']} | {r['warp']:.3f} | {r['ref']:.1f} | "
            f"{r['ref'] / r['warp']:.0f}× | {r['agree']:.4%} | {per} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
