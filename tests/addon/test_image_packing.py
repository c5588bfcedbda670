"""The engine renders shown behind the DivAS cameras are packed into the .blend at the
next idle moment and at the latest before a save — not inside the click that shows them
(a PNG encode per view). Saved and reopened, the images hold the
renders; a file loaded meanwhile drops the requests."""

from __future__ import annotations

import bpy
import numpy as np

from blender_addon import bridge, overlays


def _camera(name: str):
    cam = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    bpy.context.scene.collection.objects.link(cam)
    return cam


def _rgb(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).random((48, 64, 3), dtype=np.float32)


def _pixels(img) -> np.ndarray:
    px = np.empty(img.size[0] * img.size[1] * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(img.size[1], img.size[0], 4)[::-1, :, :3]  # top row first


def test_a_shown_render_is_packed_later_and_by_the_save(tmp_path):
    cams = [_camera(f"cam{k}") for k in range(2)]
    imgs = [overlays.set_background(c, _rgb(k)) for k, c in enumerate(cams)]
    assert all(img.packed_file is None for img in imgs)  # the click did not wait for it
    assert bpy.app.timers.is_registered(bridge._pack_timer)  # the idle moment's packing
    assert bridge.pack_pending() == 2 and all(img.packed_file is not None for img in imgs)
    assert bridge.pack_pending() == 0  # nothing twice
    # a new render behind an already packed image: packed again before the save
    overlays.set_background(cams[1], _rgb(7))
    bpy.data.images.remove(imgs[0])  # a removed camera's image: skipped
    path = tmp_path / "packed.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    img = bpy.data.images[overlays.image_name(bpy.data.objects["cam1"])]
    assert img.packed_file is not None
    np.testing.assert_allclose(_pixels(img), _rgb(7), atol=1.0 / 254)  # the newer render


def test_loading_a_file_drops_the_requests(tmp_path):
    overlays.set_background(_camera("cam"), _rgb(1))
    assert bpy.app.timers.is_registered(bridge._pack_timer)
    bpy.ops.wm.read_homefile(app_template="")
    assert not bpy.app.timers.is_registered(bridge._pack_timer)
    assert bridge.pack_pending() == 0
