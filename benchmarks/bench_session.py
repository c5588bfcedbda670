"""Latency of the interactive loop through the Session API.

Part 1 — what the user waits for, on one synthetic scene (default: the 1M-surfel
``plant``): ``Session.open`` (planned anchors, first anchor rendered), a click → centroid
view ready, a preview (segmenter, reported apart), accept → selection, and full renders
of the same centroid view (three, the median taken). All are measured in one process, side
by side, and printed as wall seconds and process CPU seconds (every thread), each also as a
ratio to that render (the machine is shared: ratios, and CPU ratios under load, are the
figures that travel).

Part 2 — per-update cost of DivAS's incremental fusion + mapping against a
FlashSplat-style re-accumulation (per-surfel blending-weight voting re-run over every
fused view at each update), at growing view counts and scene sizes.

Part 3 (``--per-update``) — the per-update table of ``divas segment`` reports.

    python benchmarks/bench_session.py [--size 1000000] [--scene plant] [--views 5,10,20]
        [--fusion-sizes 250000,1000000] [--per-update] [--device cuda]
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from divas_engine.cli.segment import segment_scene
from divas_engine.evaluation import demo_prompts
from divas_engine.io.cameras import load_cameras
from divas_engine.io.load import load_scene
from divas_engine.segment_request import SegmentRequest
from divas_engine.synthetic import generate_scene

COLS = ("render_s", "segmenter_s", "kernel_s", "mapping_s", "update_s")
CACHE = Path(os.environ.get("DIVAS_BENCH_CACHE", tempfile.gettempdir())) / "divas_bench_scenes"


def sync(device: str) -> None:
    """Wait for ``device``'s queued kernels (a CUDA launch returns before it runs)."""
    if device != "cpu":
        import warp as wp

        wp.synchronize_device(device)


def scene_files(name: str, size: int) -> Path:
    """Generate (once, cached under ``CACHE``) a synthetic scene; returns its folder."""
    out = CACHE / f"{name}_{size}"
    if not (out / "scene.ply").exists() or not (out / "labels.npy").exists():
        out.mkdir(parents=True, exist_ok=True)
        sc = generate_scene(name, out, size=size, seed=0)
        demo_prompts(sc.metadata, sc.cameras).write(out / "prompts.json")
    return out


def _first_click(folder: Path, cameras):
    from divas_engine.session.prompts import load_prompts

    pr = load_prompts(folder / "prompts.json")
    by_name = {c.name: c for c in cameras}
    ap = pr.anchors[0]
    return by_name[ap.value], [c.xy for c in ap.clicks]


def interactive(
    folder: Path, repeats: int, segmenter: str = "oracle", device: str = "cpu"
) -> dict[str, float]:
    """Median seconds of open / click / preview / accept / render on one scene, with the
    oracle (a stand-in for SAM: a value render of the ground truth) or ``graph3d`` (the
    product's default, weight-free), on ``device`` (each step waits for its kernels)."""
    from divas_engine.segment.graph3d import Graph3DSegmenter
    from divas_engine.segment.oracle import OracleSegmenter
    from divas_engine.session import Session, SessionConfig

    scene = load_scene(folder / "scene.ply")
    cameras = load_cameras(folder / "cameras.json")
    gt = np.load(folder / "labels.npy").astype(np.float32)
    cam, clicks = _first_click(folder, cameras)
    rows: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}
    c0 = [0.0]

    def put(k: str, t0: float) -> None:
        sync(device)
        rows.setdefault(k, []).append(time.perf_counter() - t0)
        cpu.setdefault(k, []).append(time.process_time() - c0[0])

    def start() -> float:
        c0[0] = time.process_time()
        return time.perf_counter()

    for _ in range(repeats):
        t = start()
        seg = OracleSegmenter() if segmenter == "oracle" else Graph3DSegmenter()
        truth = gt if segmenter == "oracle" else None
        s = Session.open(scene, cameras, SessionConfig(), seg, device, gt_values=truth)
        put("open", t)
        _ = s.grid  # waits for the background warm-up (fusion state, mapper)
        put("ready", t)
        s.wait_warm_up()  # and the segmenter's part (none for the oracle)
        put("warm", t)
        a = s.add_anchor(cam, "training", 0)
        t = start()
        s.render(a)
        put("render_anchor", t)
        views = []
        for k, xy in enumerate(clicks[:2]):
            t = start()
            views.append(s.click(a.index, xy))
            put("click" if k == 0 else "click2", t)
        for k, v in enumerate(views):
            t = start()
            s.prompt(v)
            put("preview", t)
            t = start()
            res = s.accept(v)
            put("accept" if k == 0 else "accept2", t)
            t = start()
            _ = res.overlay
            put("overlay", t)
        for _ in range(3):  # the reference: three fresh renders (the machine is noisy)
            if hasattr(s.renderer, "clear_cache"):  # the reference render shares nothing
                s.renderer.clear_cache()
                # … but follows the anchor's render, as the click does (a binning the
                # view's render may replace and recycle: SurfelRenderer.recycle_binnings)
                s.renderer.render(cam, attached=False)
            t = start()
            s.renderer.render(views[0].camera)
            put("render", t)
        s.close()
    out = {k: float(np.median(v)) for k, v in rows.items()}
    out.update({f"cpu:{k}": float(np.median(v)) for k, v in cpu.items()})
    return out


def print_interactive(
    name: str, size: int, repeats: int, segmenter: str = "oracle", device: str = "cpu"
) -> None:
    folder = scene_files(name, size)
    m = interactive(folder, repeats, segmenter, device)
    r = m["render"]
    print(f"\n## Interactive loop, {name} {size:,} surfels, {segmenter} (median of {repeats})\n")
    print(
        "| step | seconds | ratio to one render of the view | CPU s (all threads) "
        "| CPU ratio | target (ratio) |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    rc = m["cpu:render"]
    targets = {
        "open": "≤ 6",
        "click": "≤ 1.0",
        "click2": "≤ 1.0",
        "accept": "≤ 0.35",
        "accept2": "≤ 0.35",
    }
    label = {
        "open": "Session.open (returns, first anchor rendered)",
        "ready": "open → background warm-up done (fusion state, mapper)",
        "warm": "open → the segmenter's warm-up done too (graph3d: its primitives)",
        "click": "click → centroid view (1st click)",
        "click2": "click → centroid view (2nd click)",
        "preview": "preview (the segmenter's masks of the click's prompt)",
        "accept": "accept → selection (1st view)",
        "accept2": "accept → selection (2nd view)",
        "overlay": "overlay of the accepted view, when read",
        "render": "full render of the centroid view",
        "render_anchor": "full render of an anchor (640×480 training camera)",
    }
    for k in label:
        if k in m:
            c = m[f"cpu:{k}"]
            print(
                f"| {label[k]} | {m[k]:.3f} | {m[k] / r:.2f} | {c:.3f} | {c / rc:.2f} "
                f"| {targets.get(k, '')} |"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1_000_000)
    ap.add_argument("--scene", default="plant")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--views", default="5,10,20")
    ap.add_argument("--fusion-sizes", default="250000,1000000")
    ap.add_argument("--skip-interactive", action="store_true")
    ap.add_argument(
        "--segmenter",
        default="oracle",
        choices=("oracle", "graph3d"),
        help="the interactive loop's segmenter (graph3d: the product's default)",
    )
    ap.add_argument("--skip-fusion", action="store_true")
    ap.add_argument("--per-update", action="store_true", help="also the divas-segment table")
    ap.add_argument("--sizes", default="100000,500000,1000000", help="--per-update sizes")
    ap.add_argument("--segmenters", default="oracle,classic", help="--per-update segmenters")
    ap.add_argument("--device", default="cpu", help="cpu or cuda[:N] (Warp device)")
    args = ap.parse_args()
    print(
        f"# Session latency — {platform.machine()}, {os.cpu_count()} cores, "
        f"{datetime.date.today()}, device {args.device}"
    )
    if not args.skip_interactive:
        print_interactive(args.scene, args.size, args.repeats, args.segmenter, args.device)
    if not args.skip_fusion:
        from bench_fusion_vs_flashsplat import print_fusion_vs_reaccumulation

        print_fusion_vs_reaccumulation(
            args.scene,
            [int(s) for s in args.fusion_sizes.split(",")],
            [int(v) for v in args.views.split(",")],
            scene_files,
            args.device,
        )
    if args.per_update:
        per_update(args)


def per_update(args) -> None:
    print(f"\n## Per-update latency of `divas segment`, scene {args.scene}, 640×480 views\n")
    print(
        "| surfels | segmenter | active voxels | views fused | "
        + " | ".join(c.removesuffix("_s") + " ms" for c in COLS)
        + " | T_pipe s |"
    )
    print("|---:|---|---:|---:|" + "---:|" * (len(COLS) + 1))
    for n in (int(s) for s in args.sizes.split(",")):
        out = scene_files(args.scene, n)
        with tempfile.TemporaryDirectory() as tmp:
            for seg in args.segmenters.split(","):
                report, _ = segment_scene(
                    SegmentRequest(
                        out / "scene.ply",
                        out / "prompts.json",
                        cameras=out / "cameras.json",
                        out=Path(tmp) / "sel.ply",
                        segmenter=seg,
                        gt_labels=out / "labels.npy",
                        device=args.device,
                    ),
                    progress=False,
                )
                fused = [u for u in report["updates"] if u["status"] == "fused"]
                med = [
                    np.median([u[c] for u in fused if u.get(c) is not None]) * 1e3
                    if fused
                    else float("nan")
                    for c in COLS
                ]
                t_pipe = report["timings"].get(
                    "T_pipe_s", report["timings"].get("total_s", float("nan"))
                )
                print(
                    f"| {n:,} | {seg} | {report['grid'].get('n_active', '—'):,} | "
                    f"{len(fused)}/{len(report['updates'])} | "
                    + " | ".join(f"{m:.0f}" for m in med)
                    + f" | {t_pipe:.1f} |"
                )


if __name__ == "__main__":
    main()
