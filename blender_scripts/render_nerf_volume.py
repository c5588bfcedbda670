"""Segment a NeRF grid in Blender and render the segmented Volume next to the whole one.

    python blender_scripts/render_nerf_volume.py -- GRID --labels L.npy --out DIR
        [--engine CYCLES|BLENDER_EEVEE_NEXT] [--width 480] [--samples 32] [--camera I]
        [--anchors N]

(or ``blender -b --python blender_scripts/render_nerf_volume.py -- …``). Imports GRID
(``.ingp``, ``.msgpack``, ``.npz``, ``.pth``, ``.vdb``) with Import › NeRF as a Volume,
starts a DivAS session with the SAM-like oracle on ``L.npy`` (ground truth per voxel of
the grid as loaded), clicks a labelled voxel in each of the first N anchors that sees
it (``--anchors``, default 1; the clicks spread along the object), accepting each view,
makes the Segmented Volume, and renders from training camera ``I`` (the snapshot's own,
else the anchor): ``DIR/volume.png`` (the imported volume), ``DIR/segment.png`` (the
segmented volume alone) and ``DIR/side_by_side.png``; prints the timings and voxel
counts as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _args(argv):
    p = argparse.ArgumentParser(prog="render_nerf_volume.py")
    p.add_argument("grid", type=Path)
    p.add_argument("--labels", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--engine", default="CYCLES")
    p.add_argument("--width", type=int, default=480)
    p.add_argument("--samples", type=int, default=32)
    p.add_argument("--camera", type=int, default=0)
    p.add_argument("--anchors", type=int, default=1, help="anchors clicked (one click each)")
    return p.parse_args(argv)


def _render(bpy, path: Path) -> np.ndarray:
    bpy.context.scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    import cv2

    return cv2.imread(str(path), cv2.IMREAD_COLOR)


#: where the k-th click goes: quantiles along the object's longest axis (middle first)
CLICK_QUANTILES = (0.5, 0.1, 0.9, 0.3, 0.7)


def _click_target(pts: np.ndarray, k: int) -> np.ndarray:
    """The labelled voxel nearest the middle of the k-th slab (a tenth of the voxels)
    along the longest axis of ``pts``: successive clicks spread over the object."""
    axis = int(np.argmax(np.ptp(pts, 0)))
    order = np.argsort(pts[:, axis], kind="stable")
    width = max(1, len(order) // 10)
    start = round(CLICK_QUANTILES[k % len(CLICK_QUANTILES)] * (len(order) - width))
    slab = pts[order[start : start + width]]
    return slab[np.argmin(np.linalg.norm(slab - np.median(slab, 0), axis=1))]


def main(argv: list[str]) -> int:
    a = _args(argv)
    import bpy

    addon_utils = __import__("addon_utils")  # after bpy, which puts it on the path

    addon_utils.enable("blender_addon", default_set=True)
    from blender_addon import nerf_volume, session_registry

    a.out.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.read_homefile(app_template="")
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    t = time.perf_counter()
    assert bpy.ops.divas.import_density_grid(filepath=str(a.grid)) == {"FINISHED"}
    t_import = time.perf_counter() - t
    obj = bpy.context.active_object
    sc = bpy.context.scene
    sc.divas.render_scale, sc.divas.autosave = 0.5, False
    assert bpy.ops.divas.start_session(
        segmenter="oracle", gt_labels=str(a.labels), device="cpu"
    ) == {"FINISHED"}
    live = session_registry.get(obj)
    s = live.session
    labels = np.load(a.labels)
    iz, iy, ix = np.nonzero(labels & (s.scene.density > 0))
    pts = s.scene.aabb[0] + (np.stack([ix, iy, iz], 1) + 0.5) * s.scene.voxel_size
    t = time.perf_counter()
    clicked = 0
    for i, anc in enumerate(s.anchors):
        cam = anc.camera
        target = _click_target(pts, clicked)
        uv, z = cam.project(target[None])
        if z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height:
            xy = f"{uv[0, 0]!r} {uv[0, 1]!r}"
            assert bpy.ops.divas.session_click(anchor=i, xy=xy) == {"FINISHED"}
            assert bpy.ops.divas.session_accept() == {"FINISHED"}
            clicked += 1
            if clicked == a.anchors:
                break
    t_click = time.perf_counter() - t
    assert bpy.ops.divas.segmented_volume() == {"FINISHED"}
    seg = bpy.context.active_object
    # render from a training camera of the file, else the first anchor's
    cams = bpy.data.collections.get("DivAS Cameras")
    cam_objs = [o for o in cams.objects if o.type == "CAMERA"] if cams else []
    cam = cam_objs[min(a.camera, len(cam_objs) - 1)] if cam_objs else sc.camera
    sc.camera = cam
    r = sc.render
    r.engine = a.engine
    scale = a.width / max(1, r.resolution_x)
    r.resolution_x, r.resolution_y = a.width, max(1, round(r.resolution_y * scale))
    r.resolution_percentage = 100
    if a.engine == "CYCLES":
        sc.cycles.samples = a.samples
        sc.cycles.device = "CPU"
    sc.view_settings.view_transform = "Standard"
    sc.world = sc.world or bpy.data.worlds.new("World")
    sc.world.color = (0.0, 0.0, 0.0)
    vol = nerf_volume.display_volume_of(obj)
    for o in bpy.data.objects:
        if o.type in ("MESH", "LIGHT"):
            o.hide_render = True
    seg.hide_render = True
    t = time.perf_counter()
    whole = _render(bpy, a.out / "volume.png")
    seg.hide_render, vol.hide_render = False, True
    part = _render(bpy, a.out / "segment.png")
    t_render = time.perf_counter() - t
    import cv2

    cv2.imwrite(str(a.out / "side_by_side.png"), np.concatenate([whole, part], 1))
    print(
        json.dumps(
            {
                "grid": str(a.grid),
                "import_s": round(t_import, 3),
                "click_accept_s": round(t_click, 3),
                "render_two_s": round(t_render, 2),
                "voxels": int((s.scene.density > 0).sum()),
                "selected": int(seg["divas_voxels"]),
                "labelled": int(labels.sum()),
                "anchors_clicked": clicked,
                "engine": a.engine,
            }
        )
    )
    return 0


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    sys.exit(main(argv))
