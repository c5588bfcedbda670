"""The interactive loop inside Blender (bpy module, headless): Start DivAS, a click and an
accept through the add-on's operators on a synthetic plant scene with SH degree 3, with
the process RSS and a profile of each step (Blender side).

    python benchmarks/bench_blender_session.py [--size 1000000] [--profile OUT_DIR]

Per step: wall seconds, process CPU seconds, the part that is Blender's depsgraph update after
the operator, and each as a ratio to one full engine render of the clicked view (the figure to
compare across loads); the peak RSS after each step. Also the first look through another
anchor and the first read of the next view's overlay. ``--profile`` writes a cProfile text
profile per step. ``--fixed-colour`` switches *View-Dependent Colour* off (the camera-free
display variant); ``--viewport-colours`` turns the display's *Viewport Colours* on, as a 3D
view in Material Preview would (headless it is off, as in Solid mode). ``--segmenter graph3d``
runs the product's default segmenter instead of the oracle. ``--runs N`` runs N fresh processes
and prints each step's wall times, their median, the median CPU and the largest peak (one run
is not a figure: a shared machine is noisy).
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
    ap.add_argument("--fixed-colour", action="store_true", help="View-Dependent Colour off")
    ap.add_argument(
        "--viewport-colours",
        action="store_true",
        help="as with a 3D view in Material Preview: the viewport evaluates the points' SH "
        "colour (the display's Viewport Colours input on; headless it is off)",
    )
    ap.add_argument(
        "--segmenter",
        default="oracle",
        choices=("oracle", "graph3d"),
        help="oracle (ground truth, the default here) or graph3d (the product's default)",
    )
    ap.add_argument(
        "--no-prefetch",
        action="store_true",
        help="graph3d: no cut started while the clicked view renders (an A/B switch)",
    )
    ap.add_argument(
        "--no-mask-prefetch",
        action="store_true",
        help="graph3d: the masks rendered after the view, not beside it (an A/B switch)",
    )
    ap.add_argument(
        "--scratch",
        choices=("sparse", "none", "all"),
        default="sparse",
        help="renders whose working arrays reuse kept buffers (SurfelRenderer.scratch_*; "
        "sparse: what the add-on does with its heap limit at 3M)",
    )
    ap.add_argument(
        "--runs", type=int, default=1, help="fresh processes to run; the medians printed"
    )
    args = ap.parse_args()
    if args.runs > 1:
        _runs(args.runs)
        return

    import bpy  # noqa: I001 - bpy first: addon_utils ships with it

    import addon_utils

    from divas_engine.synthetic import generate_scene

    from divas_engine.render.surfel_renderer import SurfelRenderer

    SurfelRenderer.scratch_sparse = args.scratch != "none"
    SurfelRenderer.scratch_renders = args.scratch == "all"

    folder = args.cache / f"plant_{args.size}_sh3"
    if not (folder / "scene.ply").exists():
        folder.mkdir(parents=True, exist_ok=True)
        generate_scene("plant", folder, size=args.size, seed=0, sh_degree=3)
    meta_clicks = __import__("json").loads((folder / "scene.json").read_text())["clicks"]

    addon_utils.enable("blender_addon", default_set=True)
    bpy.ops.wm.read_homefile(app_template="")
    rows: list[tuple[str, float, float, float, float, float]] = []
    # time Blender's view-layer (depsgraph) updates that bpy.ops runs around an operator
    ops_cls = bpy.ops._BPyOpsSubModOp
    plain_update = ops_cls._view_layer_update
    dg = [0.0]

    def timed_update(context):
        t = time.perf_counter()
        plain_update(context)
        dg[0] += time.perf_counter() - t

    ops_cls._view_layer_update = staticmethod(timed_update)

    panel = [None]  # the live session whose panel redraws after each step

    def step(name: str, fn):
        prof = None
        bpy.context.view_layer.update()  # nothing pending from the step before
        if args.profile is not None:
            import cProfile

            prof = cProfile.Profile()
            prof.enable()
        dg[0] = 0.0
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        if panel[0] is not None:  # what the panel's redraw after the step reads
            panel[0].counts()
        dt, dc = time.perf_counter() - t, time.process_time() - c
        if prof is not None:
            import io
            import pstats

            prof.disable()
            args.profile.mkdir(parents=True, exist_ok=True)
            text = io.StringIO()
            pstats.Stats(prof, stream=text).sort_stats("cumulative").print_stats(45)
            (args.profile / f"{name.replace(' ', '_')}.txt").write_text(text.getvalue())
        rows.append((name, dt, dc, dg[0], _rss_gb(), _peak_gb()))
        return out

    from blender_addon import session_registry

    step(
        "import",
        lambda: bpy.ops.divas.import_splats(filepath=str(folder / "scene.ply"), display=True),
    )
    obj = bpy.context.active_object
    bpy.context.scene.divas.autosave = False
    if args.viewport_colours:
        from blender_addon import display

        mod = obj.modifiers[display.MODIFIER]
        vc = getattr(display.DisplayInputs, "VIEWPORT_COLOURS", None)  # (older add-ons)
        if vc in display.display_inputs(mod):
            display.set_display_inputs(mod, **{vc: True})
    if args.fixed_colour:
        from blender_addon import display

        mod = obj.modifiers[display.MODIFIER]
        display.set_display_inputs(mod, **{display.DisplayInputs.VIEW_DEPENDENT: False})
        print(f"display group: {mod.node_group.name}")
    gt = {"gt_labels": str(folder / "labels.npy")} if args.segmenter == "oracle" else {}
    step(
        "start",
        lambda: (
            bpy.ops.divas.start_session(device="cpu", segmenter=args.segmenter, **gt),
            session_registry.get(obj).counts(),  # the panel's redraw after Start
        ),
    )
    live = session_registry.get(obj)
    panel[0] = live
    s = live.session
    if hasattr(s.renderer, "scratch_sparse"):  # over the add-on's own choice
        s.renderer.scratch_sparse = args.scratch != "none"
    if hasattr(s.segmenter, "prefetch_cuts"):  # over the add-on's own choice
        s.segmenter.prefetch_cuts = not args.no_prefetch
        s.segmenter.prefetch_masks = not args.no_mask_prefetch
    # Start returns before the engine's background warm-up (fusion state, mapper) ends;
    # a user looks at the first anchor meanwhile. Timed apart, so the click is measured
    # on a warm session whichever way Start handles the warm-up
    step("background warm-up left after Start", lambda: (s.grid, s.wait_warm_up()))
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
    if xy[0] != 0:  # the user looks through the anchor before clicking on it
        step(f"look through anchor {xy[0]}", lambda: _look_through(bpy, live, xy[0]))
    step("click", lambda: bpy.ops.divas.session_click(anchor=xy[0], xy=f"{xy[1]!r} {xy[2]!r}"))
    step("accept", lambda: bpy.ops.divas.session_accept())
    v = s.views[-1]
    nxt = next((i for i, a in enumerate(s.anchors) if not a.rendered), None)
    if nxt is not None:  # the first look through an anchor not rendered yet
        step("look through another anchor (first time)", lambda: _look_through(bpy, live, nxt))
    shown = next((vid for vid in live.coverage if callable(live.coverage[vid][1])), None)
    if shown is not None:  # (an accept that renders it inside leaves no lazy overlay)
        step("overlay of the view shown next (first draw)", lambda: live.coverage_of(shown))
    from divas_engine.render import make_renderer

    ref = make_renderer(s.scene, device="cpu")
    ref.render(v.camera)  # compile/warm-up
    # a whole render: projection and binning too (a kept binning would leave the blend)
    ref.clear_cache()
    t, c = time.perf_counter(), time.process_time()
    ref.render(v.camera)
    render_s, render_cpu = time.perf_counter() - t, time.process_time() - c
    load = os.getloadavg()
    print(
        f"\n## Blender (bpy {bpy.app.version_string}), plant {args.size:,} surfels, SH 3, "
        f"View-Dependent Colour {'off' if args.fixed_colour else 'on'}, "
        f"Viewport Colours {'on' if args.viewport_colours else 'off'}, "
        f"segmenter {args.segmenter}, prefetch {'off' if args.no_prefetch else 'on'}"
        f"{' (masks after the view)' if args.no_mask_prefetch else ''}, "
        f"scratch {args.scratch}\n"
    )
    print(
        f"Reference: one full engine render of the clicked view "
        f"({v.camera.width}×{v.camera.height}) {render_s:.2f} s wall, {render_cpu:.2f} s CPU. "
        f"Load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} on {os.cpu_count()} cores.\n"
    )
    print(
        "| step | wall s | CPU s | of which depsgraph s | wall ratio to a render | "
        "CPU ratio | RSS after, GB | peak RSS so far, GB |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, dt, dc, dgs, rss, peak in rows:
        print(
            f"| {name} | {dt:.2f} | {dc:.2f} | {dgs:.2f} | {dt / render_s:.2f} | "
            f"{dc / render_cpu:.2f} | {rss:.2f} | {peak:.2f} |"
        )
    # the session's peak is the table's last column; this one adds the reference render's
    # own renderer (a second copy of the scene's surfel buffers, not part of a session)
    print(f"\npeak RSS with the bench's reference renderer {_peak_gb():.2f} GB")


def _runs(n: int) -> None:
    """Run this bench ``n`` times in fresh processes (the same arguments without
    ``--runs``); print each run's header once and a table of medians per step."""
    import subprocess

    argv, skip = [], False
    for a in sys.argv[1:]:
        if skip or a == "--runs" or a.startswith("--runs="):
            skip = a == "--runs"
            continue
        argv.append(a)
    steps: dict[str, list[list[float]]] = {}
    refs: list[float] = []
    for k in range(n):
        out = subprocess.run(
            [sys.executable, __file__, *argv], capture_output=True, text=True, check=True
        ).stdout
        for line in out.splitlines():
            if line.startswith("## ") and k == 0:
                print(line + f", {n} runs\n")
            elif line.startswith("Reference:"):
                refs.append(float(line.split(") ")[1].split(" s wall")[0]))
            cells = [c.strip() for c in line.strip("|").split("|")] if line.startswith("| ") else []
            if len(cells) == 8 and cells[0] != "step":
                vals = [float(c) for c in cells[1:]]
                steps.setdefault(cells[0], []).append(vals)
        print(f"run {k + 1}/{n} done", file=sys.stderr)
    print(f"Reference render of the clicked view, wall s: median {np.median(refs):.2f} ({refs})\n")
    print(
        "| step | wall s, each run | median wall s | median CPU s | median depsgraph s "
        "| largest peak RSS, GB |"
    )
    print("|---|---|---:|---:|---:|---:|")
    for name, rows in steps.items():
        a = np.array(rows)
        walls = ", ".join(f"{w:.2f}" for w in a[:, 0])
        print(
            f"| {name} | {walls} | {np.median(a[:, 0]):.2f} | {np.median(a[:, 1]):.2f} "
            f"| {np.median(a[:, 2]):.2f} | {a[:, 6].max():.2f} |"
        )


def _look_through(bpy, live, i: int):
    """What Look Through Camera does with anchor ``i``'s camera active."""
    cam = bpy.data.objects[live.anchor_cameras[i]]
    bpy.context.view_layer.objects.active = cam
    return bpy.ops.divas.activate_camera()


def _peak_gb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


if __name__ == "__main__":
    main()
