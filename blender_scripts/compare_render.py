"""Render an imported capture in Blender and with the engine from the same camera; write
the pictures side by side and the mean absolute differences inside the object.

    python blender_scripts/compare_render.py -- CAPTURE --out DIR
        [--engines CYCLES,BLENDER_WORKBENCH] [--width 320] [--samples 16]
        [--azimuth 30] [--elevation 15] [--up 0,-1,0] [--blend AUTO|DISPLAY|LINEAR]
        [--supersample 8]

The camera looks at the capture's robust centre from ``2.4 r_fg``; Blender renders with the
Standard view transform, a black world and a 1-pixel box filter. Engine references:
``engine`` (its own render, display-space compositing as the trainers do); ``engine_aa`` (at
``--supersample``× resolution, area-averaged in display space — what a Blender pixel integrates,
without most of the native render's 2DGS √2/2-pixel low-pass widening); ``engine_linear_aa``
(compositing in linear light, what Blender's linear blending computes). "Inside the object" is
where the engine's native alpha is > 0.5. Writes ``<name>_<engine>.png``,
``<name>_<reference>.png``, ``<name>_side_by_side.png`` and ``<name>_compare.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from divas_engine import load_scene  # noqa: E402
from divas_engine.camera import Camera  # noqa: E402
from divas_engine.point_attributes import linear_to_srgb, srgb_to_linear  # noqa: E402
from divas_engine.render import make_renderer  # noqa: E402
from divas_engine.scene import SH_C0  # noqa: E402
from divas_engine.views import scene_frame  # noqa: E402

#: engine reference supersampling: at a few hundred pixels 4× still keeps part of the
#: 2DGS low-pass (σ = √2/2 px of the 4× image) and misses sub-pixel detail (guitar,
#: 160 px: 0.061 at 4× against 0.030 at 8×, Cycles 64 samples).
SUPERSAMPLE = 8


def view_camera(scene, width: int, azimuth: float, elevation: float, up) -> Camera:
    """A ``width × ¾width`` camera at ``2.4 r_fg`` from the robust centre."""
    fr = scene_frame(scene)
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    side = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    side /= np.linalg.norm(side)
    fwd = np.cross(side, up)
    az, el = math.radians(azimuth), math.radians(elevation)
    d = math.cos(el) * (math.cos(az) * side + math.sin(az) * fwd) + math.sin(el) * up
    h = width * 3 // 4
    return Camera.look_at(
        fr.center + 2.4 * fr.radius * d, fr.center, up, width=width, height=h, fx=1.1 * width
    )


def _area_down(img: np.ndarray, f: int) -> np.ndarray:
    h, w = img.shape[0] // f, img.shape[1] // f
    return img[: h * f, : w * f].reshape(h, f, w, f, -1).mean(axis=(1, 3))


def engine_references(
    path: Path, cam: Camera, supersample: int = SUPERSAMPLE
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``({name: [H,W,3] display RGB in [0,1]}, inside mask)`` (module docstring)."""
    scene = load_scene(path)
    ren = make_renderer(scene, "cpu")
    native = ren.render(cam)
    refs = {"engine": np.clip(native.rgb, 0, 1)}
    big = cam.scaled(supersample)
    refs["engine_aa"] = np.clip(_area_down(np.clip(ren.render(big).rgb, 0, 1), supersample), 0, 1)
    dc = np.maximum(0.5 + SH_C0 * scene.sh[:, 0].astype(np.float64), 0.0)
    scene.sh[:, 0] = ((srgb_to_linear(dc) - 0.5) / SH_C0).astype(np.float32)
    if scene.sh_degree:  # linear compositing of the DC colour only (SH add in display space)
        scene.sh[:, 1:] = 0.0
    lin = np.maximum(make_renderer(scene, "cpu").render(big).rgb, 0.0)
    refs["engine_linear_aa"] = np.clip(linear_to_srgb(_area_down(lin, supersample)), 0, 1)
    return refs, native.alpha > 0.5


def render_blender(context, obj, cam: Camera, engine: str, samples: int, out: Path) -> np.ndarray:
    """``[H,W,3]`` display RGB of ``obj`` seen through ``cam`` (a camera in the object's
    file frame), rendered by ``engine`` to ``out``."""
    import bpy

    from blender_addon import camera_objects, compat

    scene = context.scene
    bcam = camera_objects.create_camera_object(
        cam, scene.collection, name="DivAS compare", frame=np.array(obj.matrix_world)
    )
    camera_objects.apply_render_settings(scene, bcam)
    world = scene.world or bpy.data.worlds.new("World")
    scene.world = world
    world.color = (0.0, 0.0, 0.0)
    if world.node_tree is not None and "Background" in world.node_tree.nodes:
        world.node_tree.nodes["Background"].inputs[0].default_value = (0, 0, 0, 1)
    scene.view_settings.view_transform = "Standard"
    scene.render.engine = compat.render_engine(engine)  # EEVEE's name differs on 4.x
    scene.render.image_settings.file_format = "PNG"
    scene.render.film_transparent = False
    if engine == "CYCLES":
        c = scene.cycles
        c.device, c.samples, c.use_denoising = "CPU", samples, False
        c.pixel_filter_type, c.filter_width = "BOX", 1.0
    elif engine in ("BLENDER_EEVEE", "BLENDER_EEVEE_NEXT"):
        scene.eevee.taa_render_samples = samples
    else:
        shading = scene.display.shading
        shading.light, shading.color_type = "FLAT", "VERTEX"
        shading.background_type, shading.background_color = "VIEWPORT", (0, 0, 0)
    scene.render.filepath = str(out)
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(out), check_existing=False)
    px = np.empty(img.size[0] * img.size[1] * img.channels, np.float32)
    img.pixels.foreach_get(px)
    w, h, ch = img.size[0], img.size[1], img.channels
    bpy.data.images.remove(img)
    return px.reshape(h, w, ch)[::-1, :, :3].astype(np.float64)


def mad(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    return float(np.abs(a - b).mean(-1)[mask].mean())


def _png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    cv2.imwrite(str(path), (np.clip(rgb, 0, 1)[..., ::-1] * 255 + 0.5).astype(np.uint8))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[sys.argv.index("--") + 1 :] if argv is None and "--" in sys.argv else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--engines", default="CYCLES,BLENDER_WORKBENCH")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--azimuth", type=float, default=30.0)
    ap.add_argument("--elevation", type=float, default=15.0)
    ap.add_argument("--up", default="0,-1,0", help="the capture's up in its own frame")
    ap.add_argument("--supersample", type=int, default=SUPERSAMPLE)
    ap.add_argument(
        "--blend", default="AUTO", choices=("AUTO", "DISPLAY", "LINEAR"), help="import option"
    )
    args = ap.parse_args(argv)
    import bpy  # noqa: I001 - bpy first: it puts addon_utils on the path
    import addon_utils

    addon_utils.enable("blender_addon", default_set=True)
    bpy.ops.wm.read_homefile(app_template="")
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    done = bpy.ops.divas.import_splats(filepath=str(args.capture), blend_space=args.blend)
    assert done == {"FINISHED"}
    obj = bpy.context.active_object
    up = [float(v) for v in args.up.split(",")]
    cam = view_camera(load_scene(args.capture), args.width, args.azimuth, args.elevation, up)
    refs, inside = engine_references(args.capture, cam, args.supersample)
    args.out.mkdir(parents=True, exist_ok=True)
    name = args.capture.name.split(".")[0]
    if name == "meta":
        name = args.capture.parent.name
    report = {
        "capture": str(args.capture),
        "size": [cam.width, cam.height],
        "blend_display": bool(getattr(bpy.context.scene, "divas_blend_display", False)),
        "mad": {},
    }
    row = []
    for k, v in refs.items():
        _png(args.out / f"{name}_{k}.png", v)
    for eng in args.engines.split(","):
        rgb = render_blender(
            bpy.context, obj, cam, eng, args.samples, args.out / f"{name}_{eng}.png"
        )
        report["mad"][eng] = {k: round(mad(rgb, v, inside), 4) for k, v in refs.items()}
        row.append(rgb)
    _png(args.out / f"{name}_side_by_side.png", np.concatenate([refs["engine"], *row], axis=1))
    (args.out / f"{name}_compare.json").write_text(json.dumps(report, indent=1))
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
