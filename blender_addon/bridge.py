"""The one place where NumPy arrays cross into Blender and back.

Every per-point value goes through :func:`write_attribute` / :func:`read_attribute`:
bulk ``foreach_set`` / ``foreach_get`` on attribute data with C-contiguous arrays of
exactly the type Blender stores (float32, int32, bool), which Blender copies as one
memory block. Never a per-point Python loop.

Point clouds: ``bpy.data.pointclouds.new`` makes an *empty* point cloud, and before 5.2
``PointCloud.points`` cannot be resized from Python (``object.convert`` to a point cloud
exists only from 4.5). :func:`new_point_cloud_object` therefore gives the empty cloud a
Geometry Nodes modifier whose *Points* node makes ``n`` points and applies it (one route
on every release from 4.2), then writes positions and attributes in bulk. A real point
cloud (rather than a vertex-only mesh) is what Blender renders as points in Cycles and
EEVEE, carries the built-in ``radius``, has no edit-mode cost at millions of elements,
and is what Geometry Nodes treats as splats.
"""

from __future__ import annotations

import sys

import bpy
import numpy as np

__all__ = [
    "new_point_cloud_object",
    "write_attribute",
    "write_attributes",
    "read_attribute",
    "read_attributes",
    "attribute_names",
    "point_count",
    "remove_attribute",
    "write_image",
    "pack_soon",
    "pack_pending",
    "forget_pending",
]

#: Blender data type → (foreach property, NumPy dtype, components per element).
_TYPES = {
    "FLOAT": ("value", np.float32, 1),
    "INT": ("value", np.int32, 1),
    "BOOLEAN": ("value", bool, 1),
    "INT8": ("value", np.int32, 1),
    "FLOAT_VECTOR": ("vector", np.float32, 3),
    "FLOAT2": ("vector", np.float32, 2),
    "FLOAT_COLOR": ("color", np.float32, 4),
    "BYTE_COLOR": ("color", np.float32, 4),
    "QUATERNION": ("value", np.float32, 4),
    "INT32_2D": ("value", np.int32, 2),
    "INT16_2D": ("value", np.int32, 2),
    "FLOAT4X4": ("value", np.float32, 16),
}


def _data_type_for(values: np.ndarray) -> str:
    comps = 1 if values.ndim == 1 else values.shape[1]
    kind = values.dtype.kind
    if kind == "b" and comps == 1:
        return "BOOLEAN"
    if kind in "iu" and comps == 1:
        return "INT"
    if kind in "iu" and comps == 2:
        return "INT32_2D"
    if kind == "f":
        by_comps = {1: "FLOAT", 2: "FLOAT2", 3: "FLOAT_VECTOR", 4: "FLOAT_COLOR", 16: "FLOAT4X4"}
        if comps in by_comps:
            return by_comps[comps]
    raise ValueError(f"no Blender attribute type for an array of {values.dtype} {values.shape}")


def point_count(geometry) -> int:
    """Elements in the point domain (point cloud points or mesh vertices)."""
    points = getattr(geometry, "points", None)
    return len(points if points is not None else geometry.vertices)


#: :attr:`divas_engine.point_attributes.PointTable.kinds` → Blender data type.
_KIND_TYPES = {"color": "FLOAT_COLOR", "quaternion": "QUATERNION"}


def write_attribute(
    geometry,
    name: str,
    values: np.ndarray,
    *,
    data_type: str | None = None,
    kind: str | None = None,
):
    """Create or overwrite the point attribute ``name`` from ``values`` (``[N]`` or ``[N,k]``).

    The type follows ``data_type``, else ``kind`` (``"color"``, ``"quaternion"``: a
    (w, x, y, z) rotation), else the array (float → FLOAT/FLOAT2/FLOAT_VECTOR/FLOAT_COLOR,
    int32 → INT, bool → BOOLEAN). An existing attribute of another type or domain is
    replaced.
    """
    values = np.asarray(values)
    data_type = data_type or _KIND_TYPES.get(kind or "") or _data_type_for(values)
    prop, dtype, comps = _TYPES[data_type]
    n = point_count(geometry)
    if len(values) != n or values.size != n * comps:
        raise ValueError(f"attribute {name!r}: {values.shape} values for {n} points of {data_type}")
    attr = geometry.attributes.get(name)
    if attr is not None and (attr.data_type != data_type or attr.domain != "POINT"):
        geometry.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = geometry.attributes.new(name, data_type, "POINT")
    attr.data.foreach_set(prop, np.ascontiguousarray(values, dtype=dtype).reshape(-1))
    return attr


def write_attributes(geometry, columns: dict[str, np.ndarray]) -> None:
    for name, values in columns.items():
        write_attribute(geometry, name, values)


def read_attribute(geometry, name: str) -> np.ndarray:
    """Values of point attribute ``name`` as ``[N]`` or ``[N,k]`` (float32/int32/bool)."""
    attr = geometry.attributes.get(name)
    if attr is None:
        raise KeyError(f"{geometry.name!r} has no attribute {name!r}")
    if attr.domain != "POINT":
        raise ValueError(f"attribute {name!r} is on the {attr.domain} domain, not POINT")
    prop, dtype, comps = _TYPES[attr.data_type]
    n = point_count(geometry)
    out = np.empty(n * comps, dtype=dtype)
    attr.data.foreach_get(prop, out)
    return out if comps == 1 else out.reshape(n, comps)


def attribute_names(geometry, *, include_internal: bool = False) -> list[str]:
    """Point-domain attributes that :func:`read_attribute` can read, in storage order."""
    return [
        a.name
        for a in geometry.attributes
        if a.domain == "POINT"
        and a.data_type in _TYPES
        and (include_internal or not a.name.startswith("."))
    ]


def read_attributes(geometry, names: list[str] | None = None) -> dict[str, tuple[str, np.ndarray]]:
    """``{name: (data_type, values)}`` for ``names`` (default: every readable attribute)."""
    names = attribute_names(geometry) if names is None else names
    return {n: (geometry.attributes[n].data_type, read_attribute(geometry, n)) for n in names}


def remove_attribute(geometry, name: str) -> None:
    attr = geometry.attributes.get(name)
    if attr is not None:
        geometry.attributes.remove(attr)


def _points_group(n: int) -> bpy.types.GeometryNodeTree:
    """A throw-away Geometry Nodes group whose output is ``n`` points at the origin."""
    ng = bpy.data.node_groups.new(".divas new points", "GeometryNodeTree")
    ng.is_modifier = True
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    points = ng.nodes.new("GeometryNodePoints")
    points.inputs["Count"].default_value = n
    ng.links.new(points.outputs[0], ng.nodes.new("NodeGroupOutput").inputs[0])
    return ng


def new_point_cloud_object(name: str, positions: np.ndarray, collection) -> bpy.types.Object:
    """A new point-cloud object of ``len(positions)`` points linked into ``collection``.

    See the module docstring for why the points come from an applied Geometry Nodes
    modifier. ``collection`` must be part of the active view layer (applying evaluates
    the object).
    """
    positions = np.ascontiguousarray(positions, dtype=np.float32).reshape(-1, 3)
    n = len(positions)
    if n == 0:
        raise ValueError("a point cloud needs at least one point")
    if n > np.iinfo(np.int32).max:
        raise ValueError(f"{n:,} points: a Blender point cloud holds at most 2^31 - 1")
    cloud = bpy.data.pointclouds.new(name)
    obj = bpy.data.objects.new(name, cloud)
    collection.objects.link(obj)
    group = _points_group(n)
    try:
        mod = obj.modifiers.new("DivAS points", "NODES")
        mod.node_group = group
        with bpy.context.temp_override(
            object=obj, active_object=obj, selected_objects=[obj], selected_editable_objects=[obj]
        ):
            result = bpy.ops.object.modifier_apply(modifier=mod.name)
    except RuntimeError as e:  # the operator's poll or report, e.g. a hidden collection
        result = {"CANCELLED", str(e)}
    finally:
        bpy.data.node_groups.remove(group)
    if "FINISHED" not in result or obj.type != "POINTCLOUD" or len(obj.data.points) != n:
        bpy.data.objects.remove(obj)
        raise RuntimeError(f"could not make the point cloud {name!r} of {n:,} points")
    cloud = obj.data
    cloud.name = name
    for internal in [a.name for a in cloud.attributes if a.name != "position"]:
        remove_attribute(cloud, internal)  # the Points node's radius; written when needed
    write_attribute(cloud, "position", positions)
    return obj


def write_image(name: str, rgba: np.ndarray) -> bpy.types.Image:
    """The 8-bit sRGB image ``name`` holding ``rgba`` (``[H,W,4]`` float in [0,1], top row
    first), created or resized as needed; one bulk ``pixels.foreach_set`` (Blender stores
    rows bottom-up, so the rows are flipped here)."""
    rgba = np.asarray(rgba, dtype=np.float32)
    if rgba.ndim != 3 or rgba.shape[2] != 4:
        raise ValueError(f"image {name!r}: expected [H,W,4] RGBA, got {rgba.shape}")
    h, w = rgba.shape[:2]
    img = bpy.data.images.get(name)
    if img is not None and (tuple(img.size) != (w, h) or img.is_float):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=False)
    img.pixels.foreach_set(np.ascontiguousarray(np.clip(rgba[::-1], 0.0, 1.0)).reshape(-1))
    img.update()
    return img


# ----------------------------------------------------------------------------- packing
#: seconds after a request that the idle timer packs the images (the user looks at them)
PACK_DELAY_S = 0.5
#: images written since they were last packed (by name)
_unpacked: set[str] = set()


def pack_soon(img: bpy.types.Image) -> None:
    """Pack ``img`` into the .blend at the next idle moment (a one-shot timer) and at the
    latest before the file is saved (:func:`pack_pending` from ``save_pre``), instead of
    now: packing encodes a PNG, which a click or a first look through an anchor then
    does not wait for. Blender's own auto-save runs no
    ``save_pre``: one made within :data:`PACK_DELAY_S` of a click holds that image
    unpacked (the engine's render, not the user's data)."""
    _unpacked.add(img.name)
    if not bpy.app.timers.is_registered(_pack_timer):
        bpy.app.timers.register(_pack_timer, first_interval=PACK_DELAY_S)


def pack_pending() -> int:
    """Pack every image :func:`pack_soon` was asked for that still exists; returns how
    many were packed."""
    done = 0
    for name in sorted(_unpacked):
        img = bpy.data.images.get(name)
        if img is not None:
            img.pack()
            done += 1
    _unpacked.clear()
    return done


def forget_pending() -> None:
    """Drop the requests (another file is being loaded: the names were the old file's)."""
    _unpacked.clear()
    if bpy.app.timers.is_registered(_pack_timer):
        bpy.app.timers.unregister(_pack_timer)


def _pack_timer() -> None:
    try:
        pack_pending()
    except (ReferenceError, RuntimeError) as e:  # never raise into Blender's event loop
        print(f"DivAS: could not pack the view images yet ({e})", file=sys.stderr)
    return None  # one shot
