"""OpenVDB ``.vdb`` density grids (Blender, Houdini, EmberGen), through an OpenVDB module.

The module is ``openvdb`` (OpenVDB ≥ 11, Blender ≥ 4.4), ``pyopenvdb`` (older Blender) or the
``openvdb`` an installed ``bpy`` wheel bundles, loaded by path (the engine never imports
``bpy``). Without one, reading raises one :class:`~divas_engine.errors.DivasInputError` and
writing goes through the NumPy writer (:mod:`.vdb_writer`). Reading: the float grid
``density`` (else the first float grid) and a vector grid ``color``/``Cd``, on the active
voxels' box grown by one background cell (the support of the renderers' trilinear field), or
on the lattice box a file :func:`write_vdb` wrote records; voxel ``(i, j, k)`` is centred at
``indexToWorld(i, j, k)`` (axis-aligned scale and translation only). Writing: ``density`` (a
fog volume, background 0) and ``color``. Why the margin: docs/design-notes.md.
"""

from __future__ import annotations

import glob
import importlib
import importlib.util
import os
import sys
from functools import lru_cache
from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..scene import DensityGrid, SourceInfo
from .limits import inflate_budget, limits, require_input_file

__all__ = [
    "openvdb_module",
    "bundled_openvdb_files",
    "read_vdb",
    "write_vdb",
    "vdb_available",
    "check_vdb_structure",
    "NO_OPENVDB",
]

NO_OPENVDB = (
    "needs an OpenVDB Python module: inside Blender (it bundles one), with the bpy wheel "
    "installed, or with an 'openvdb'/'pyopenvdb' module importable"
)
_COLOR_NAMES = ("color", "Cd", "colour", "rgb")
#: grid metadata :func:`write_vdb` records: the index box of the lattice it wrote
LATTICE_MIN, LATTICE_MAX = "divas_lattice_min", "divas_lattice_max"


@lru_cache(maxsize=1)
def openvdb_module():
    """The OpenVDB Python module, or None (module docstring).

    The one finder the engine and the Blender add-on share: an importable ``openvdb`` or
    ``pyopenvdb`` first (inside Blender, or after ``bpy.utils.expose_bundled_modules``),
    else the extension module inside an installed ``bpy`` wheel, loaded by path and
    registered under its own name so a later ``import openvdb`` gets the same module
    (an extension module's types must be registered once per process)."""
    for name in ("openvdb", "pyopenvdb"):
        try:
            return importlib.import_module(name)
        except ImportError:
            continue
    for so in bundled_openvdb_files():
        name = os.path.basename(so).split(".")[0]  # openvdb (Blender ≥ 4.4) or pyopenvdb
        try:
            s = importlib.util.spec_from_file_location(name, so)
            mod = importlib.util.module_from_spec(s)
            sys.modules[name] = mod
            s.loader.exec_module(mod)
            return mod
        except (ImportError, OSError):
            sys.modules.pop(name, None)
            continue
    return None


def bundled_openvdb_files() -> list[str]:
    """The OpenVDB extension modules an installed ``bpy`` wheel carries in its Python's
    ``site-packages`` (``openvdb`` from Blender 4.4; empty for wheels without one)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.origin:
        return []
    root = os.path.dirname(spec.origin)
    site = os.path.join(root, "*", "python", "lib", "python3*", "site-packages")
    pats = [os.path.join(site, "*openvdb*" + ext) for ext in (".so", ".pyd")]
    return sorted(p for pat in pats for p in glob.glob(pat))


def vdb_available() -> bool:
    return openvdb_module() is not None


def _module(path) -> object:
    vdb = openvdb_module()
    if vdb is None:
        raise DivasInputError(path, f".vdb {NO_OPENVDB}")
    return vdb


def _axis_transform(grid, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(origin, voxel)``: world centre of voxel (0,0,0) and the per-axis voxel edge."""
    t = grid.transform
    o = np.asarray(t.indexToWorld((0, 0, 0)), np.float64)
    cols = [
        np.asarray(t.indexToWorld(tuple(int(i == a) for i in range(3))), np.float64) - o
        for a in range(3)
    ]
    M = np.stack(cols, 1)
    vox = np.diag(M).copy()
    if np.any(np.abs(M - np.diag(vox)) > 1e-9 * np.abs(vox).max()) or np.any(vox <= 0):
        raise DivasInputError(path, "grid transform is not an axis-aligned scale and translation")
    return o, vox


def read_vdb(path: str | PathLike) -> DensityGrid:
    """Load a ``.vdb`` density grid (module docstring); NaN/Inf densities become 0."""
    path = require_input_file(path, "OpenVDB file")
    vdb = _module(path)
    try:
        return _read(vdb, path)
    except DivasInputError:
        raise
    except Exception as e:  # the bindings raise RuntimeError/ValueError/IOError on bad files
        raise DivasInputError(path, f"not a readable OpenVDB file ({e})") from None


class _Bytes:
    def __init__(self, data: bytes, path: Path):
        self.d, self.o, self.path = data, 0, path

    def take(self, n: int) -> bytes:
        if n < 0 or self.o + n > len(self.d):
            raise DivasInputError(self.path, "truncated OpenVDB file")
        b = self.d[self.o : self.o + n]
        self.o += n
        return b

    def num(self, fmt: str):
        import struct

        return struct.unpack("<" + fmt, self.take(struct.calcsize(fmt)))[0]

    def text(self) -> str:
        n = self.num("I")
        if n > 4096:
            raise DivasInputError(self.path, f"OpenVDB string of {n} bytes")
        try:
            return self.take(n).decode("utf-8")
        except UnicodeDecodeError:
            raise DivasInputError(self.path, "OpenVDB name is not UTF-8") from None

    def meta_map(self) -> None:
        count = self.num("i")
        if not 0 <= count <= 4096:
            raise DivasInputError(self.path, f"{count} metadata entries")
        for _ in range(count):
            self.text()
            kind = self.text()
            size = self.num("i")
            value = self.take(size)
            if kind == "string":
                try:
                    value.decode("utf-8")
                except UnicodeDecodeError:
                    raise DivasInputError(self.path, "OpenVDB metadata is not UTF-8") from None


#: bytes of each transform map's data after its type name (OpenVDB's ``Map::read``: the
#: ``Vec3d``/``Mat4d`` members it stores); other maps (frustum) are not axis-aligned
_MAP_BYTES = {
    "TranslationMap": 24,
    "ScaleMap": 120,
    "UniformScaleMap": 120,
    "ScaleTranslateMap": 144,
    "UniformScaleTranslateMap": 144,
    "AffineMap": 128,
    "UnitaryMap": 128,
}
#: bytes of one value of a tree's value type (``Tree_<type>_5_4_3``), stored full size
_VALUE_BYTES = {
    "float": 4,
    "double": 8,
    "int32": 4,
    "int64": 8,
    "uint32": 4,
    "bool": 1,
    "mask": 1,
    "vec3s": 12,
    "vec3d": 24,
    "vec3i": 12,
}
#: the least one root child takes in the topology: its origin and an internal node's
#: child and value masks (32³ bits each)
_ROOT_CHILD_BYTES = 12 + 2 * 4096


def check_vdb_structure(path: Path) -> None:
    """Walk the file's header, metadata, grid descriptors and each grid's root node
    (OpenVDB's ``Archive``, ``GridDescriptor``, ``Map`` and ``RootNode`` layouts) and
    refuse a file whose names are not UTF-8, whose offsets leave the file, or whose root
    node counts more tiles or children than its topology block can hold: OpenVDB's
    Python bindings abort the whole process when an error message they convert holds
    non-UTF-8 bytes, and its reader loops (and allocates) once per counted entry even
    past the end of the stream, so a corrupted count would hang it."""
    b = _Bytes(path.read_bytes(), path)
    if b.num("q") != 0x56444220:
        raise DivasInputError(path, "not an OpenVDB file (bad magic number)")
    version = b.num("I")
    if not 213 <= version <= 1024:
        raise DivasInputError(path, f"OpenVDB file version {version} is not supported")
    b.num("I"), b.num("I")
    has_offsets = b.num("b")
    if 220 <= version < 222:
        b.num("I")
    b.take(36)
    if not has_offsets:
        raise DivasInputError(path, "OpenVDB file without grid offsets is not supported")
    b.meta_map()
    n = b.num("i")
    if not 0 <= n <= 1024:
        raise DivasInputError(path, f"{n} grids")
    size = len(b.d)
    for _ in range(n):
        name, gtype, parent = b.text(), b.text(), b.text()
        grid_pos, block_pos, end_pos = b.num("q"), b.num("q"), b.num("q")
        if not (0 < grid_pos <= block_pos <= end_pos <= size):
            raise DivasInputError(path, "OpenVDB grid offsets outside the file")
        g = _Bytes(b.d[:block_pos], path)
        g.o = grid_pos
        if version >= 222:
            g.num("I")
        g.meta_map()
        map_type = g.text()
        if not parent:  # an instance shares its parent's tree and stores none
            _check_root(g, map_type, gtype, name)
        b.o = end_pos


def _check_root(g: _Bytes, map_type: str, gtype: str, name: str) -> None:
    """The root node's tile and child counts fit the topology block (``g`` ends there)."""
    if map_type not in _MAP_BYTES:
        raise DivasInputError(g.path, f"grid {name!r} has a {map_type!r} transform")
    g.take(_MAP_BYTES[map_type])
    half = gtype.endswith("_HalfFloat")
    value = gtype.removesuffix("_HalfFloat").split("_")
    vbytes = _VALUE_BYTES.get(value[1] if len(value) > 1 else "")
    if vbytes is None:
        return  # not a grid DivAS reads (points, strings): OpenVDB never parses its tree
    if half and value[1] in ("float", "vec3s"):
        vbytes //= 2
    g.num("i")  # buffer count
    g.take(vbytes)  # background
    tiles, children = g.num("I"), g.num("I")
    room = len(g.d) - g.o
    if tiles * (13 + vbytes) + children * _ROOT_CHILD_BYTES > room:
        raise DivasInputError(
            g.path,
            f"grid {name!r} counts {tiles} tiles and {children} children at its root, more "
            f"than its {room} bytes of topology hold (a corrupted or truncated file)",
        )


def _lattice_box(meta: dict, lo, hi) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The index box the dense lattice covers: the one :func:`write_vdb` recorded
    (``divas_lattice_min/max``) when it holds the active box ``lo..hi``, else the active
    box grown by one background cell on every side (module docstring)."""
    lo = tuple(int(v) for v in lo)
    hi = tuple(int(v) for v in hi)
    try:
        a = np.asarray(meta[LATTICE_MIN], np.float64).reshape(3)
        b = np.asarray(meta[LATTICE_MAX], np.float64).reshape(3)
    except (KeyError, TypeError, ValueError):
        a = b = None
    if (
        a is not None
        and np.all(np.isfinite(a) & np.isfinite(b))
        and np.all(a == np.rint(a))
        and np.all(b == np.rint(b))
        and np.all(a <= lo)
        and np.all(b >= hi)
        and np.all(b - a >= 1)
    ):
        return tuple(int(v) for v in a), tuple(int(v) for v in b)
    return tuple(v - 1 for v in lo), tuple(v + 1 for v in hi)


def _read(vdb, path: Path) -> DensityGrid:
    check_vdb_structure(path)
    metas = vdb.readAllGridMetadata(str(path))
    floats = [g for g in metas if g.valueTypeName in ("float", "double")]
    if not floats:
        raise DivasInputError(path, "holds no float grid (expected a 'density' grid)")
    dens_meta = next((g for g in floats if g.name == "density"), floats[0])
    col_meta = next(
        (g for g in metas if g.name in _COLOR_NAMES and g.valueTypeName.startswith("vec3")), None
    )
    budget = inflate_budget(path.stat().st_size)
    for g in (dens_meta, col_meta):
        if g is None:
            continue
        md = g.metadata
        if "file_bbox_min" in md and "file_bbox_max" in md:
            n = np.prod(np.asarray(md["file_bbox_max"]) - np.asarray(md["file_bbox_min"]) + 1)
            per = 4 if g is dens_meta else 12
            if n * per > budget or n > limits().max_rows:
                raise DivasInputError(
                    path, f"grid {g.name!r} spans {int(n)} voxels, over the limit"
                )
    dgrid = vdb.read(str(path), dens_meta.name)
    cgrid = vdb.read(str(path), col_meta.name) if col_meta is not None else None
    lo_ijk, hi_ijk = dgrid.evalActiveVoxelBoundingBox()
    if min(int(b - a + 1) for a, b in zip(lo_ijk, hi_ijk)) < 1 or dgrid.activeVoxelCount() == 0:
        raise DivasInputError(path, f"empty scene: grid {dgrid.name!r} has no active voxel")
    lo_ijk, hi_ijk = _lattice_box(dens_meta.metadata, lo_ijk, hi_ijk)
    shape = tuple(b - a + 1 for a, b in zip(lo_ijk, hi_ijk))
    if int(np.prod(shape)) * 4 > budget or int(np.prod(shape)) > limits().max_rows:
        raise DivasInputError(path, f"grid spans {shape} voxels, over the LoadLimits budget")
    arr = np.zeros(shape, np.float32)
    dgrid.copyToArray(arr, ijk=lo_ijk)
    origin, vox = _axis_transform(dgrid, path)
    lo = origin + (np.asarray(lo_ijk, np.float64) - 0.5) * vox
    density = np.ascontiguousarray(arr.transpose(2, 1, 0))
    bad = ~np.isfinite(density)
    n_bad = int(bad.sum())
    density[bad] = 0
    density = np.maximum(density, 0)
    rgb = None
    if cgrid is not None:
        c = np.zeros(shape + (3,), np.float32)
        cgrid.copyToArray(c, ijk=lo_ijk)
        rgb = np.clip(np.nan_to_num(c.transpose(2, 1, 0, 3)), 0, 1).astype(np.float32)
    if not np.any(density > 0):
        raise DivasInputError(path, "empty scene: the density grid is zero everywhere")
    aabb = np.stack([lo, lo + np.asarray(shape) * vox])
    src = SourceInfo(path, "vdb", int(density.size), None, n_bad)
    out = DensityGrid(density, aabb, rgb, src)
    out.extras["vdb_grid_name"] = dgrid.name
    return out


def write_vdb(path: str | PathLike, grid: DensityGrid, density: np.ndarray | None = None) -> Path:
    """Write ``grid`` (or ``density`` on its lattice instead of its own) as ``.vdb``:
    through the OpenVDB module (compressed), else :mod:`.vdb_writer` (plain bytes)."""
    from ..output_paths import atomic_path

    dens = np.asarray(grid.density if density is None else density, np.float32)
    vox = grid.voxel_size
    centre0 = np.asarray(grid.aabb[0], np.float64) + 0.5 * vox
    box = {LATTICE_MIN: (0, 0, 0), LATTICE_MAX: tuple(int(n) - 1 for n in dens.shape[::-1])}
    rgb = None
    if grid.rgb is not None:
        rgb = np.where((dens > 0)[..., None], grid.rgb, 0).astype(np.float32)
    vdb = openvdb_module()
    if vdb is None:
        from .vdb_writer import write_vdb_numpy

        grids = [("density", dens.transpose(2, 1, 0))]
        if rgb is not None:
            grids.append(("color", rgb.transpose(2, 1, 0, 3)))
        with atomic_path(path) as tmp:
            write_vdb_numpy(tmp, grids, centre0, vox, {"density": box})
        return Path(path)
    M = [[vox[0], 0, 0, 0], [0, vox[1], 0, 0], [0, 0, vox[2], 0], [*centre0.tolist(), 1]]
    g = vdb.FloatGrid()
    g.copyFromArray(np.ascontiguousarray(dens.transpose(2, 1, 0)))
    g.name = "density"
    for k, v in box.items():
        g[k] = v
    g.gridClass = vdb.GridClass.FOG_VOLUME
    g.transform = vdb.createLinearTransform([[float(v) for v in row] for row in M])
    grids = [g]
    if rgb is not None:
        c = vdb.Vec3SGrid()
        c.copyFromArray(np.ascontiguousarray(rgb.transpose(2, 1, 0, 3)))
        c.name = "color"
        c.transform = vdb.createLinearTransform([[float(v) for v in row] for row in M])
        grids.append(c)
    with atomic_path(path) as tmp:
        vdb.write(str(tmp), grids=grids)
    return Path(path)
