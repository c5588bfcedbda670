"""The interactive loop inside Blender (bpy module, headless): Start DivAS, a click and an
accept through the add-on's operators on a synthetic plant scene with SH degree 3, with
the process RSS and a profile of each step (issue 20, Blender side).

    python benchmarks/bench_blender_session.py [--size 1000000] [--profile OUT_DIR]

Every figure is wall time of one operator call on this machine (shared: compare with
the engine-only figures of ``bench_session.py`` from the same run). With ``--profile``,
a pyinstrument text profile of each step is written to OUT_DIR (the evidence of where
the add-on's time goes).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the add-on package

import numpy as np


def _rss_gb() -> float:
    import psutil

    return psutil.Process(os.getpid()).memory_info().rss / 2**30


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1_000_000)
    ap.add_argument("--profile", type=Path, default=None)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/divas_bench_scenes"))
    args = ap.parse_args()

    import bpy  # noqa: I001 - bpy first: addon_utils ships with it

    import addon_utils

    from divas_engine.synthetic import generate_scene

    folder = args.cache / f"plant_{args.size}_sh3"
    if not (folder / "scene.ply").exists():
        folder.mkdir(parents=True, exist_ok=True)
        generate_scene("plant", folder, size=args.size, seed=0, sh_degree=3)
    meta_clicks = __import__("json").loads((folder / "scene.json").read_text())["clicks"]

    addon_utils.enable("blender_addon", default_set=True)
    bpy.ops.wm.read_homefile(app_template="")
    rows: list[tuple[str, float, float]] = []

    def step(name: str, fn):
        prof = None
        if args.profile is not None:
            from pyinstrument import Profiler

            prof = Profiler()
            prof.start()
        t = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t
        if prof is not None:
            prof.stop()
            args.profile.mkdir(parents=True, exist_ok=True)
            (args.profile / f"{name}.txt").write_text(prof.output_text(unicode=True))
        rows.append((name, dt, _rss_gb()))
        return out

    from blender_addon import session_registry

    step(
        "import",
        lambda: bpy.ops.divas.import_splats(filepath=str(folder / "scene.ply"), display=True),
    )
    obj = bpy.context.active_object
    bpy.context.scene.divas.autosave = False
    step(
        "start",
        lambda: bpy.ops.divas.start_session(
            device="cpu", segmenter="oracle", gt_labels=str(folder / "labels.npy")
        ),
    )
    live = session_registry.get(obj)
    s = live.session
    xy = None
    for i, a in enumerate(s.anchors):
        for c in meta_clicks:
            uv, z = a.camera.project(np.array([c["xyz"]]))
            if z[0] > 0 and 0 <= uv[0, 0] < a.camera.width and 0 <= uv[0, 1] < a.camera.height:
                xy = (i, float(uv[0, 0]), float(uv[0, 1]))
                break
        if xy:
            break
    if xy is None:
        raise SystemExit("no metadata click is visible in an anchor")
    step("click", lambda: bpy.ops.divas.session_click(anchor=xy[0], xy=f"{xy[1]!r} {xy[2]!r}"))
    step("accept", lambda: bpy.ops.divas.session_accept())
    print(f"\n## Blender (bpy {bpy.app.version_string}), plant {args.size:,} surfels, SH 3\n")
    print("| step | seconds | RSS after, GB |")
    print("|---|---:|---:|")
    for name, dt, rss in rows:
        print(f"| {name} | {dt:.2f} | {rss:.2f} |")


if __name__ == "__main__":
    main()
