"""Per-update latency of the interactive loop (issue 6): render, segmenter, fusion kernel,
voxel-to-surfel mapping and overlay, per accepted centroid view, on this machine.

Runs ``divas segment`` (the real Session) on synthetic scenes of growing size with the
scripted demo prompts (4 target clicks × 3 training cameras = 12 centroid views) and prints
the median per-update figures from the report.

    python benchmarks/bench_session.py [--sizes 100000,500000,1000000] [--scene plant]
"""

from __future__ import annotations

import argparse
import datetime
import platform
import tempfile
from pathlib import Path

import numpy as np

from divas_engine.cli.segment import segment_scene
from divas_engine.evaluation import demo_prompts
from divas_engine.synthetic import generate_scene

COLS = ("render_s", "segmenter_s", "kernel_s", "mapping_s", "overlay_s", "update_s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100000,500000,1000000")
    ap.add_argument("--scene", default="plant")
    ap.add_argument("--segmenters", default="oracle,classic")
    args = ap.parse_args()
    print(
        f"# Session per-update latency — {platform.machine()}, {datetime.date.today()}, "
        f"scene {args.scene}, 640×480 views, device cpu"
    )
    print(
        "| surfels | segmenter | active voxels | views fused | "
        + " | ".join(c.removesuffix("_s") + " ms" for c in COLS)
        + " | T_pipe s |"
    )
    print("|---:|---|---:|---:|" + "---:|" * (len(COLS) + 1))
    for n in (int(s) for s in args.sizes.split(",")):
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp)
            sc = generate_scene(args.scene, out, size=n, seed=0)
            demo_prompts(sc.metadata, sc.cameras).write(out / "prompts.json")
            for seg in args.segmenters.split(","):
                report, _ = segment_scene(
                    out / "scene.ply",
                    out / "prompts.json",
                    cameras_path=out / "cameras.json",
                    out=out / "sel.ply",
                    segmenter=seg,
                    gt_labels=out / "labels.npy",
                    device="cpu",
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
