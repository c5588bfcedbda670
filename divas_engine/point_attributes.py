"""Per-point attribute tables for hosts that show a scene as points (the Blender add-on).

Pure NumPy (no ``bpy``): a host gets ``positions [N,3]`` and an ordered ``{name: array}`` it
writes one attribute per entry, so no format knowledge lives in the host. Every value is stored
once, so a scene of millions of splats fits in memory and in a ``.blend``.

* :func:`surfel_point_table` — one point per primitive: ``divas_index`` (file row),
  ``divas_color`` (linear RGB decoded from the sRGB SH DC colour, A = opacity),
  ``divas_rotation`` (w, x, y, z), ``divas_scale``, optional ``divas_sh_<k>`` (three 8-bit codes
  packed in one int32, :func:`quantize_sh`; display only) and the PLY's non-standard
  properties (``ply_``-prefixed when a host reserves the name);
* :func:`grid_point_table` — one point per voxel of a density grid above an opacity threshold.

The attributes in full: docs/design-notes.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .scene import SH_C0, DensityGrid, SurfelScene, sh_coeff_count

__all__ = [
    "PointTable",
    "ENGINE_COLUMNS",
    "RESERVED_NAMES",
    "STANDARD_PLY_PROPERTIES",
    "SELECTED",
    "INDEX",
    "COLOR",
    "ROTATION",
    "SCALE",
    "sh_attribute_name",
    "surfel_point_table",
    "grid_point_table",
    "display_radius",
    "srgb_to_linear",
    "linear_to_srgb",
    "quantize_sh",
    "dequantize_sh",
    "scene_selection",
    "point_values",
]

INDEX = "divas_index"
SELECTED = "divas_selected"
COLOR = "divas_color"
ROTATION = "divas_rotation"
SCALE = "divas_scale"
ENGINE_COLUMNS = (INDEX, COLOR, ROTATION, SCALE)
#: attribute names a point-cloud host uses for its own data.
RESERVED_NAMES = frozenset({"position", "radius", "id"})
#: display radius = RADIUS_SIGMAS × geometric-mean tangent σ, clipped at this percentile.
RADIUS_SIGMAS = 2.0
RADIUS_CLIP_PERCENTILE = 99.0
#: percentile of |coefficient| per SH band that sets its 8-bit range (outliers clip).
SH_RANGE_PERCENTILE = 99.9
#: rows the SH range percentile is taken over (evenly strided).
SH_RANGE_SAMPLE = 200_000


def _is_standard(name: str) -> bool:
    """A 3DGS/2DGS trainer property the engine decodes (kept once, as engine columns)."""
    if name in {"x", "y", "z", "nx", "ny", "nz", "opacity"}:
        return True
    for prefix in ("f_dc_", "f_rest_", "scale_", "rot_"):
        if name.startswith(prefix) and name[len(prefix) :].isdigit():
            return True
    return False


STANDARD_PLY_PROPERTIES = "x y z nx ny nz f_dc_* f_rest_* opacity scale_* rot_*"


def sh_attribute_name(k: int) -> str:
    """Point attribute of SH coefficient ``k`` (1 … 15) of R, G, B (:func:`quantize_sh`)."""
    return f"divas_sh_{k}"


@dataclass(frozen=True, eq=False)
class PointTable:
    """Points for a host: ``positions [N,3]`` float32 and ordered ``columns``.

    Column arrays are C-contiguous: float32 ``[N]`` / ``[N,3]`` / ``[N,4]``, int32
    ``[N]`` or bool ``[N]``. ``kinds`` names the columns a host must not store by
    shape alone (``"color"`` for an RGBA ``[N,4]``, ``"quaternion"`` for a (w,x,y,z)
    rotation); ``meta`` holds per-scene values a host keeps beside the points
    (``sh_range``: the three per-band ranges of the ``divas_sh_*`` codes;
    ``max_radius``: the P99 display radius; ``sh_degree``).
    """

    positions: np.ndarray
    columns: dict[str, np.ndarray]
    kinds: dict[str, str] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.positions)


def _float(x) -> np.ndarray:
    """float32 arrays stay float32 (millions of colours), anything else becomes float64."""
    x = np.asarray(x)
    return x if x.dtype == np.float32 else x.astype(np.float64)


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding, extended sign-symmetrically outside [0, 1]."""
    c = _float(c)
    a = np.abs(c)
    lin = np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)
    return np.copysign(lin, c).astype(c.dtype, copy=False)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_to_linear` (sRGB encoding, extended the same way)."""
    x = _float(x)
    a = np.abs(x)
    enc = np.where(a <= 0.0031308, a * 12.92, 1.055 * a ** (1 / 2.4) - 0.055)
    return np.copysign(enc, x).astype(x.dtype, copy=False)


def _band_of(k: int) -> int:
    return int(np.floor(np.sqrt(k)))


def quantize_sh(sh_rest: np.ndarray, degree: int) -> tuple[list[np.ndarray], np.ndarray]:
    """8-bit codes of the view-dependent SH coefficients.

    Args:
        sh_rest: ``[N, K−1, 3]`` coefficients 1 … K−1 (``SurfelScene.sh[:, 1:]``).
        degree: SH degree 1 … 3.

    Returns:
        ``(codes, ranges)``: per coefficient k an ``[N]`` int32 of packed R, G, B codes
        (``r + 256 g + 65536 b``), and ``ranges [3]`` (band 1, 2, 3; 0 beyond
        ``degree`` or for an all-zero band): the ``SH_RANGE_PERCENTILE`` of |c| over the
        band. A code c ∈ [1, 255] means ``(c − 128) / 127 · range``, so 0 is exact and
        every value within the range is kept to half a step (``range / 254``); values
        beyond it clip.
    """
    ranges = np.zeros(3, np.float64)
    codes = []
    n = len(sh_rest)
    # the range from at most SH_RANGE_SAMPLE rows (evenly strided, deterministic): a
    # percentile over millions of rows costs seconds and moves the range by < 1 %
    sample = sh_rest[:: max(1, n // SH_RANGE_SAMPLE)]
    for band in range(1, degree + 1):
        block = sample[:, band * band - 1 : (band + 1) ** 2 - 1]
        if block.size:
            ranges[band - 1] = float(np.percentile(np.abs(block), SH_RANGE_PERCENTILE))
    k1 = sh_coeff_count(degree) - 1
    r = ranges[[_band_of(k) - 1 for k in range(1, k1 + 1)]]
    scale = np.where(r > 0, 127.0 / np.where(r > 0, r, 1.0), 0.0).astype(np.float32)[:, None]
    packed = np.empty((k1, n), np.int32)
    for lo in range(0, n, 1 << 18):  # row blocks: vectorised over coefficients, small memory
        c = np.rint(np.asarray(sh_rest[lo : lo + (1 << 18)], np.float32) * scale)
        np.clip(c, -127, 127, out=c)
        c = c.astype(np.int32) + 128
        packed[:, lo : lo + len(c)] = (c[..., 0] | (c[..., 1] << 8) | (c[..., 2] << 16)).T
    codes = list(packed)
    return codes, ranges


def dequantize_sh(codes: list[np.ndarray], ranges: np.ndarray) -> np.ndarray:
    """``[N, len(codes), 3]`` coefficients from :func:`quantize_sh`'s codes."""
    out = np.empty((len(codes[0]) if codes else 0, len(codes), 3), np.float64)
    for j, v in enumerate(codes):
        v = np.asarray(v, np.int64)
        rgb = np.stack([v & 255, (v >> 8) & 255, (v >> 16) & 255], 1).astype(np.float64)
        out[:, j] = (rgb - 128.0) / 127.0 * ranges[_band_of(j + 1) - 1]
    return out


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


def _ply_extra_columns(path, kept_rows: np.ndarray) -> dict[str, np.ndarray]:
    """Raw values of the non-standard vertex properties at ``kept_rows`` (ascending)."""
    from .io.ply import iter_vertex_chunks, read_ply_header

    layout = read_ply_header(path)
    dtype = layout.vertex_dtype()
    names = [n for n in dtype.names if not _is_standard(n)]
    if not names:
        return {}
    out = {n: np.empty(len(kept_rows), _as_column(np.zeros(1, dtype[n])).dtype) for n in names}
    for start, chunk in iter_vertex_chunks(layout):
        lo, hi = np.searchsorted(kept_rows, [start, start + len(chunk)])
        if hi == lo:
            continue
        rows = chunk[kept_rows[lo:hi] - start]
        for n in names:
            out[n][lo:hi] = _as_column(rows[n])
    return {_host_name(n): v for n, v in out.items()}


def display_radius(scales: np.ndarray) -> np.ndarray:
    """``[N]`` float32 point radius for display: ``RADIUS_SIGMAS · sqrt(s1·s2)``, clipped."""
    r = RADIUS_SIGMAS * np.sqrt(scales[:, 0].astype(np.float64) * scales[:, 1])
    if len(r):
        r = np.minimum(r, np.percentile(r, RADIUS_CLIP_PERCENTILE))
    return r.astype(np.float32)


def surfel_point_table(scene: SurfelScene, *, sh_display: bool = True) -> PointTable:
    """The :class:`PointTable` of a surfel scene (see the module docstring).

    ``sh_display``: include the ``divas_sh_*`` codes (view-dependent colour) when the
    scene has SH degree ≥ 1.
    """
    src = scene.source
    n = len(scene)
    cols: dict[str, np.ndarray] = {}
    if src is not None and src.format == "ply":
        cols.update(_ply_extra_columns(src.path, src.kept_rows))
    index = src.kept_rows if src is not None else np.arange(n)
    if len(index) and index.max() > np.iinfo(np.int32).max:
        raise ValueError("scene has more file rows than an int32 index can address")
    color = np.empty((n, 4), np.float32)
    color[:, :3] = srgb_to_linear(np.float32(0.5) + np.float32(SH_C0) * scene.sh[:, 0, :])
    color[:, 3] = scene.opacities
    scale = np.zeros((n, 3), np.float32)
    scale[:, :2] = scene.scales
    if scene.scale_n is not None:
        scale[:, 2] = scene.scale_n
    cols[INDEX] = index.astype(np.int32)
    cols[COLOR] = color
    cols[ROTATION] = np.ascontiguousarray(scene.quats, dtype=np.float32)
    cols[SCALE] = scale
    meta: dict = {"sh_degree": int(scene.sh_degree), "sh_range": [0.0, 0.0, 0.0]}
    if sh_display and scene.sh_degree > 0:
        codes, ranges = quantize_sh(scene.sh[:, 1:], scene.sh_degree)
        for k, c in enumerate(codes, start=1):
            cols[sh_attribute_name(k)] = c
        meta["sh_range"] = [float(r) for r in ranges]
    radius = display_radius(scene.scales)
    meta["max_radius"] = float(radius.max()) if n else 0.0
    kinds = {COLOR: "color", ROTATION: "quaternion"}
    return PointTable(np.ascontiguousarray(scene.means, dtype=np.float32), cols, kinds, meta)


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
        color[:, :3] = srgb_to_linear(grid.rgb.reshape(-1, 3)[flat])
    else:
        color[:, :3] = srgb_to_linear(a)[:, None]
    color[:, 3] = a
    radius = 0.5 * float(np.min(vox))
    cols = {
        INDEX: flat.astype(np.int32),
        "divas_density": grid.density.ravel()[flat].astype(np.float32),
        COLOR: color,
        "divas_radius": np.full(len(flat), radius, np.float32),
    }
    meta = {"sh_degree": 0, "sh_range": [0.0, 0.0, 0.0], "max_radius": radius}
    return PointTable(pos.astype(np.float32), cols, {COLOR: "color"}, meta)


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
