"""The first look after an import: what Solid mode and Material Preview draw, and a frame of each.

    python benchmarks/bench_first_look.py [--splats 150000 1000000] [--size 1280 720]
    python benchmarks/bench_first_look.py --pictures DIR [--capture PLY]

Run it with the Python of the ``bpy`` release to measure (``.venv-bpy42/bin/python …``).

Timing: a synthetic 3DGS PLY per size imported with the add-on's defaults by a fresh ``bpy``
process, then the startup camera's view rendered by Workbench (Solid) and EEVEE (Material
Preview, one sample). ``first_s`` is the first frame (Geometry Nodes evaluation, geometry sync,
draw), ``frame_s`` the median of ``--frames`` more renders (an upper bound of a viewport
redraw), ``empty_frame_s`` the same frame before the import. ``bpy`` draws with whatever
OpenGL it finds: compare shadings and sizes here, not seconds with a GPU viewport.

Pictures: ``--capture`` (default: the guitar in ``tests/data``) seen through the first
hand-placed anchor of its target, in Solid mode (``<name>_solid.png``) and Material Preview
converged (``<name>_first_look.png``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
GUITAR = REPO / "tests" / "data" / "playcanvas-splats" / "guitar.compressed.ply"


def _fresh_scene():
    import importlib

    import bpy

    addon_utils = importlib.import_module("addon_utils")  # importable once bpy is

    if str(REPO) not in sys.path:
        sys.path.insert(0, str(REPO))
    addon_utils.enable("blender_addon", default_set=True)
    bpy.ops.wm.read_homefile(app_template="")
    cube = bpy.data.objects.get("Cube")
    if cube is not None:
        bpy.data.objects.remove(cube)
    for obj in bpy.data.objects:
        if obj.type == "LIGHT":  # Material Preview lights with its studio world, not these
            obj.hide_render = True
    display = bpy.context.scene.display
    display.render_aa = display.viewport_aa  # Solid mode's anti-aliasing in the viewport
    return bpy


def _render(bpy, engine: str, samples: int, path: Path | None = None) -> float:
    """Seconds to render the scene camera's view with ``engine`` (written to ``path``)."""
    from blender_addon import compat

    scene = bpy.context.scene
    scene.render.engine = compat.render_engine(engine)
    if engine == "BLENDER_EEVEE":
        scene.eevee.taa_render_samples = samples
    else:
        scene.display.shading.light = "STUDIO"  # Solid mode's default
    scene.render.image_settings.file_format = "PNG"
    if path is not None:
        scene.render.filepath = str(path)
    t = time.perf_counter()
    bpy.ops.render.render(write_still=path is not None)
    return time.perf_counter() - t


def child_timing(ply: str, size: tuple[int, int], frames: int) -> dict:
    bpy = _fresh_scene()
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    shadings = (("solid", "BLENDER_WORKBENCH"), ("material_preview", "BLENDER_EEVEE"))
    empty = {}
    for shading, engine in shadings:  # the frame's cost without splats
        _render(bpy, engine, 1)
        empty[shading] = statistics.median(_render(bpy, engine, 1) for _ in range(frames))
    t = time.perf_counter()
    assert bpy.ops.divas.import_splats(filepath=ply) == {"FINISHED"}
    obj = bpy.context.active_object
    out = {"blender": bpy.app.version_string, "import_s": time.perf_counter() - t}
    out["points"] = len(obj.data.points)
    for shading, engine in shadings:
        first = _render(bpy, engine, 1)
        rest = [_render(bpy, engine, 1) for _ in range(frames)]
        frame = statistics.median(rest)
        out[shading] = {"first_s": first, "frame_s": frame, "empty_frame_s": empty[shading]}
    return out


def child_pictures(capture: str, out_dir: str) -> dict:
    import numpy as np

    bpy = _fresh_scene()
    from blender_addon import camera_objects
    from divas_engine import load_scene
    from divas_engine.evaluation.real_targets import oracle_anchors, read_targets

    capture, out_dir = Path(capture), Path(out_dir)
    assert bpy.ops.divas.import_splats(filepath=str(capture)) == {"FINISHED"}
    obj = bpy.context.active_object
    name = capture.name.split(".")[0]
    scene = bpy.context.scene
    targets = REPO / "tests" / "data" / "targets" / name
    doc = read_targets(targets)
    first_target = next(iter(doc["targets"].values()))
    cam, *_ = oracle_anchors(load_scene(capture), doc["true_up"], first_target["anchors"])[0]
    bcam = camera_objects.create_camera_object(
        cam, scene.collection, name="first look", frame=np.array(obj.matrix_world)
    )
    camera_objects.apply_render_settings(scene, bcam)
    scene.camera = bcam
    out_dir.mkdir(parents=True, exist_ok=True)
    solid = out_dir / f"{name}_solid.png"
    look = out_dir / f"{name}_first_look.png"
    _render(bpy, "BLENDER_WORKBENCH", 1, solid)
    _render(bpy, "BLENDER_EEVEE", scene.eevee.taa_samples, look)
    return {"blender": bpy.app.version_string, "pictures": [str(solid), str(look)]}


def _child(kind: str, payload: dict) -> dict:
    code = (
        f"import json, sys; sys.path.insert(0, {str(REPO)!r}); "
        "from benchmarks.bench_first_look import child_" + kind + " as f; "
        f"print('RESULT ' + json.dumps(f(**json.loads({json.dumps(payload)!r}))))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    line = [ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")]
    if res.returncode or not line:
        raise SystemExit(res.stdout[-3000:] + res.stderr[-3000:])
    return json.loads(line[0][7:])


def _rounded(v):
    if isinstance(v, dict):
        return {k: _rounded(x) for k, x in v.items()}
    return round(v, 3) if isinstance(v, float) else v


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--splats", type=int, nargs="+", default=[150_000, 1_000_000])
    ap.add_argument("--size", type=int, nargs=2, default=[1280, 720])
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--pictures", type=Path, default=None, help="write the pictures here")
    ap.add_argument("--capture", type=Path, default=GUITAR)
    args = ap.parse_args(argv)
    if args.pictures is not None:
        res = _child("pictures", {"capture": str(args.capture), "out_dir": str(args.pictures)})
        print(json.dumps(res))
        return 0
    sys.path.insert(0, str(REPO))
    from benchmarks.bench_blender_import import make_ply

    folder = REPO / "build" / "bench"
    folder.mkdir(parents=True, exist_ok=True)
    for n in args.splats:
        ply = folder / f"gauss_{n}_sh3.ply"
        if not ply.exists():
            make_ply(ply, n, 3)
        res = _child("timing", {"ply": str(ply), "size": args.size, "frames": args.frames})
        res["size"] = args.size
        res["load_average"] = [round(x, 1) for x in os.getloadavg()]
        print(json.dumps(_rounded(res)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
