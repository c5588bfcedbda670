"""Where a camera's image lies in a 3D-viewport region, and which pixel a click hits.

The geometry is pure (:mod:`divas_engine.viewport`); this module only asks Blender for
the camera frame corners (``Camera.view_frame`` through ``matrix_world``) in region
coordinates (``view3d_utils.location_3d_to_region_2d``). The frame Blender draws
follows ``scene.render`` (size and pixel aspect), so the camera's own render settings
must be applied (:func:`.camera_objects.apply_render_settings`) before looking through it.
"""

from __future__ import annotations

import numpy as np
from bpy_extras import view3d_utils

from divas_engine.viewport import region_to_camera_pixel

from .camera_objects import blender_params

__all__ = ["camera_frame_in_region", "click_to_camera_pixel"]


def camera_frame_in_region(region, rv3d, scene, cam_obj) -> np.ndarray | None:
    """``[4,2]`` frame corners (top-right, bottom-right, bottom-left, top-left) in region
    coordinates, or None when a corner is behind the view."""
    mw = cam_obj.matrix_world.normalized()
    out = []
    for corner in cam_obj.data.view_frame(scene=scene):
        p = view3d_utils.location_3d_to_region_2d(region, rv3d, mw @ corner)
        if p is None:
            return None
        out.append((p.x, p.y))
    return np.array(out, dtype=np.float64)


def click_to_camera_pixel(
    region, rv3d, scene, cam_obj, mouse_region: tuple[int, int]
) -> tuple[float, float] | None:
    """Continuous pixel ``(u, v)`` of ``cam_obj``'s image under a click, or None outside it."""
    frame = camera_frame_in_region(region, rv3d, scene, cam_obj)
    if frame is None:
        return None
    size = blender_params(scene, cam_obj).render_size
    return region_to_camera_pixel((region.width, region.height), frame, mouse_region, size)
