"""Per-point attribute tables for hosts that show a scene as points (the Blender add-on).

Pure NumPy (no ``bpy``): a host gets ``positions [N,3]`` and an ordered ``{name: array}``
it writes one attribute per entry, so no format knowledge lives in the host.

Surfel scenes (:func:`surfel_point_table`), one point per scene primitive (rows dropped
on load for NaN/Inf are absent):

* **File columns.** Standard PLY: every vertex property, the *raw stored* value of the
  file row (log-scales, logit opacity, …). Float properties become float32 (``double``
  ones are rounded: the host has no 64-bit attribute type), integer properties int32
  (``uint`` bit-cast, so the bits round-trip exactly). Compressed PLY: the raw
  ``packed_*`` words (bit-cast int32) and the bytes of the ``sh`` element as
  ``sh_<property>``, *plus* the decoded values as below. ``.splat`` / ``.spz`` /
  generated scenes: the decoded values only, under the 2DGS-trainer PLY names the
  engine writes (:func:`~divas_engine.io.ply.write_surfel_ply`): ``x y z f_dc_* f_rest_*
  opacity scale_0 scale_1 rot_0..3`` (stored space; 3DGS Gaussians are flattened to
  surfels on load, so two scales).
* **Engine columns** (:data:`ENGINE_COLUMNS`): ``divas_index`` int32 file row (what
  export needs), ``divas_color [N,4]`` RGBA (RGB from SH DC, A = opacity),
  ``divas_opacity`` α, ``divas_radius`` display radius.

Density grids (:func:`grid_point_table`): one point per voxel whose cell opacity
``1 − exp(−σ·voxel)`` reaches a threshold, at the cell centre, with ``divas_index``
(flat ``[iz,iy,ix]`` index into ``density``), ``divas_density`` σ, ``divas_opacity``,
``divas_color`` (the grid's rgb, or grey by opacity) and ``divas_radius`` (half a cell).

Names a host reserves (:data:`RESERVED_NAMES`, leading ``.``, the ``divas_`` prefix) are
prefixed ``ply_`` when they come from a file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import DensityGrid, SurfelScene, sh_coeff_count

__all__ = [
    "PointTable",
    "ENGINE_COLUMNS",
    "RESERVED_NAMES",
    "SELECTED",
    "INDEX",
    "surfel_point_table",
    "grid_point_table",
    "display_radius",
    "decoded_columns",
    "scene_selection",
    "point_values",
]

INDEX = "divas_index"
SELECTED = "divas_selected"
ENGINE_COLUMNS = (INDEX, "divas_color", "divas_opacity", "divas_radius")
#: attribute names a point-cloud host uses for its own data.
RESERVED_NAMES = frozenset({"position", "radius", "id"})
#: display radius = RADIUS_SIGMAS × geometric-mean tangent σ, clipped at this percentile.
RADIUS_SIGMAS = 2.0
RADIUS_CLIP_PERCENTILE = 99.0


@dataclass(frozen=True, eq=False)
class PointTable:
    """Points for a host: ``positions [N,3]`` float32 and ordered ``columns``.

    Column arrays are C-contiguous: float32 ``[N]`` / ``[N,3]`` / ``[N,4]`` (the
    ``[N,4]`` one is a colour), int32 ``[N]`` or bool ``[N]``.
    """

    positions: np.ndarray
    columns: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.positions)


def _host_name(name: str) -> str:
    if name in RESERVED_NAMES or name.startswith(".") or name.startswith("divas_"):
        return f"ply_{name}"
    return name


def _as_column(values: np.ndarray) -> np.ndarray:
    """Raw values → float32 or int32 column (uint32 bit-cast, others widened)."""
    v = np.asarray(values)
    v = v.astype(v.dtype.newbyteorder("="), copy=False)
    if v.dtype.kind == "f":
        return np.ascontiguousarray(v, dtype=np.float32)
    if v.dtype.kind in "iu" and v.dtype.itemsize == 4:
        return np.ascontiguousarray(v).view(np.int32)
    if v.dtype.kind in "iu":
        return np.ascontiguousarray(v, dtype=np.int32)
    raise ValueError(f"unsupported column dtype {v.dtype}")


def _ply_columns(path, kept_rows: np.ndarray) -> dict[str, np.ndarray]:
    """Raw values of every vertex property at ``kept_rows`` (ascending file rows)."""
    from .io.ply import iter_vertex_chunks, read_ply_header

    layout = read_ply_header(path)
    dtype = layout.vertex_dtype()
    out = {
        n: np.empty(len(kept_rows), _as_column(np.zeros(1, dtype[n])).dtype) for n in dtype.names
    }
    for start, chunk in iter_vertex_chunks(layout):
        lo, hi = np.searchsorted(kept_rows, [start, start + len(chunk)])
        if hi == lo:
            continue
        rows = chunk[kept_rows[lo:hi] - start]
        for n in dtype.names:
            out[n][lo:hi] = _as_column(rows[n])
    return {_host_name(n): v for n, v in out.items()}


def _compressed_ply_columns(path, kept_rows: np.ndarray) -> dict[str, np.ndarray]:
    """Raw ``packed_*`` words of the vertex element and the ``sh`` element's bytes."""
    import plyfile

    ply = plyfile.PlyData.read(str(path))
    out = {}
    for el, prefix in (("vertex", ""), ("sh", "sh_")):
        if el not in ply:
            continue
        data = ply[el].data
        for n in data.dtype.names:
            out[_host_name(prefix + n)] = _as_column(data[n][kept_rows])
    return out


def decoded_columns(scene: SurfelScene) -> dict[str, np.ndarray]:
    """Stored-space values of the engine's surfels under 2DGS-trainer PLY names."""
    k = sh_coeff_count(scene.sh_degree)
    cols = {a: np.ascontiguousarray(scene.means[:, i]) for i, a in enumerate("xyz")}
    for ch in range(3):
        cols[f"f_dc_{ch}"] = np.ascontiguousarray(scene.sh[:, 0, ch])
    for ch in range(3):
        for j in range(k - 1):
            cols[f"f_rest_{ch * (k - 1) + j}"] = np.ascontiguousarray(scene.sh[:, j + 1, ch])
    o = np.clip(scene.opacities.astype(np.float64), 1e-7, 1 - 1e-7)
    cols["opacity"] = np.log(o / (1 - o)).astype(np.float32)
    with np.errstate(divide="ignore"):
        for i in range(2):
            cols[f"scale_{i}"] = np.log(scene.scales[:, i]).astype(np.float32)
    for i in range(4):
        cols[f"rot_{i}"] = np.ascontiguousarray(scene.quats[:, i])
    return cols


def display_radius(scales: np.ndarray) -> np.ndarray:
    """``[N]`` float32 point radius for display: ``RADIUS_SIGMAS · sqrt(s1·s2)``, clipped."""
    r = RADIUS_SIGMAS * np.sqrt(scales[:, 0].astype(np.float64) * scales[:, 1])
    if len(r):
        r = np.minimum(r, np.percentile(r, RADIUS_CLIP_PERCENTILE))
    return r.astype(np.float32)


def surfel_point_table(scene: SurfelScene) -> PointTable:
    """The :class:`PointTable` of a surfel scene (see the module docstring)."""
    src = scene.source
    n = len(scene)
    if src is not None and src.format == "ply":
        cols = _ply_columns(src.path, src.kept_rows)
    elif src is not None and src.format == "compressed_ply":
        cols = _compressed_ply_columns(src.path, src.kept_rows)
        cols.update(decoded_columns(scene))
    else:
        cols = decoded_columns(scene)
    index = src.kept_rows if src is not None else np.arange(n)
    if len(index) and index.max() > np.iinfo(np.int32).max:
        raise ValueError("scene has more file rows than an int32 index can address")
    color = np.empty((n, 4), np.float32)
    color[:, :3] = scene.base_colors()
    color[:, 3] = scene.opacities
    cols[INDEX] = index.astype(np.int32)
    cols["divas_color"] = color
    cols["divas_opacity"] = np.ascontiguousarray(scene.opacities, dtype=np.float32)
    cols["divas_radius"] = display_radius(scene.scales)
    return PointTable(np.ascontiguousarray(scene.means, dtype=np.float32), cols)


def grid_point_table(grid: DensityGrid, min_opacity: float = 0.01) -> PointTable:
    """Occupied voxels of a density grid as points (cell opacity ≥ ``min_opacity``)."""
    vox = grid.voxel_size
    step = float(np.mean(vox))
    alpha = 1.0 - np.exp(-grid.density.astype(np.float64) * step)
    flat = np.flatnonzero(alpha.ravel() >= min_opacity)
    if flat.size == 0:
        raise ValueError(f"no voxel reaches opacity {min_opacity}")
    if flat.max() > np.iinfo(np.int32).max:
        raise ValueError("density grid too large for an int32 voxel index")
    iz, iy, ix = np.unravel_index(flat, grid.density.shape)
    pos = grid.aabb[0] + (np.stack([ix, iy, iz], 1) + 0.5) * vox
    a = alpha.ravel()[flat].astype(np.float32)
    color = np.empty((len(flat), 4), np.float32)
    if grid.rgb is not None:
        color[:, :3] = grid.rgb.reshape(-1, 3)[flat]
    else:
        color[:, :3] = a[:, None]
    color[:, 3] = a
    cols = {
        INDEX: flat.astype(np.int32),
        "divas_density": grid.density.ravel()[flat].astype(np.float32),
        "divas_color": color,
        "divas_opacity": a,
        "divas_radius": np.full(len(flat), 0.5 * float(np.min(vox)), np.float32),
    }
    return PointTable(pos.astype(np.float32), cols)


def scene_selection(
    scene: SurfelScene | DensityGrid, index: np.ndarray, selected: np.ndarray
) -> np.ndarray:
    """Engine selection mask from a host's per-point ``divas_index`` and bool selection.

    Surfel scenes: ``[len(scene)]`` bool over the scene's primitives (``index`` holds file
    rows). Density grids: ``[D,H,W]`` bool (``index`` holds flat voxel indices). Raises
    ``ValueError`` when an index is not part of ``scene`` (the points came from another
    file).
    """
    index = np.asarray(index, dtype=np.int64)
    selected = np.asarray(selected, dtype=bool)
    if index.shape != selected.shape:
        raise ValueError(f"index {index.shape} and selection {selected.shape} differ in shape")
    rows = index[selected]
    if isinstance(scene, DensityGrid):
        if rows.size and (rows.min() < 0 or rows.max() >= scene.density.size):
            raise ValueError("voxel index outside the density grid")
        mask = np.zeros(scene.density.size, bool)
        mask[rows] = True
        return mask.reshape(scene.density.shape)
    kept = scene.source.kept_rows if scene.source is not None else np.arange(len(scene))
    pos = np.searchsorted(kept, rows)
    if rows.size and (
        pos.max() >= len(kept) or np.any(kept[np.minimum(pos, len(kept) - 1)] != rows)
    ):
        raise ValueError("point index is not a primitive of this scene")
    mask = np.zeros(len(scene), bool)
    mask[pos] = True
    return mask


def point_values(scene: SurfelScene | DensityGrid, index: np.ndarray, values: np.ndarray):
    """Per-point values of per-primitive ``values`` for a host's points whose
    ``divas_index`` is ``index`` — the inverse of :func:`scene_selection`.

    Surfel scenes: ``values [len(scene)]`` over the scene's primitives (``index`` holds
    file rows). Density grids: ``values [D,H,W]`` (``index`` holds flat voxel indices).
    Returns ``[len(index)]``: the value at each point, in ``index``'s order. Raises
    ``ValueError`` when an index is not part of ``scene`` (the points came from another
    file).
    """
    index = np.asarray(index, dtype=np.int64)
    values = np.asarray(values)
    if isinstance(scene, DensityGrid):
        if index.size and (index.min() < 0 or index.max() >= scene.density.size):
            raise ValueError("voxel index outside the density grid")
        return values.reshape(-1)[index]
    kept = scene.source.kept_rows if scene.source is not None else np.arange(len(scene))
    pos = np.minimum(np.searchsorted(kept, index), len(kept) - 1)
    if index.size and np.any(kept[pos] != index):
        raise ValueError("point index is not a primitive of this scene")
    return values[pos]
