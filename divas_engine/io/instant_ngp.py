"""instant-ngp NeRF snapshots: ``.ingp`` (gzip'd msgpack) and ``.msgpack`` (raw).

The file (``NVlabs/instant-ngp`` ``src/testbed.cu``: ``Testbed::save_snapshot`` l. 5288-5355,
``load_snapshot`` l. 5358-5470) is the network config with a ``snapshot`` map: tiny-cuda-nn's
trainer state (``params_binary``), ``density_grid_binary`` (float16 cascades of 128³ cells in
Morton order holding the optical thickness ``σ·STEPSIZE``, −1 where no camera sees),
``nerf.aabb_scale``, ``nerf.dataset`` (``scale``, ``offset``, training ``xforms``) and
``aabb``. A training-frame point ``p`` is at ``ngp = cycle(p·scale + offset)`` with
``cycle(x, y, z) = (y, z, x)`` (``nerf_loader.h`` l. 91-151). The reader returns the grid and
the training cameras in the training cameras' frame, σ per unit of that frame
(``σ_ngp · scale``). Layout, cascades and frames in full: docs/design-notes.md.
"""

from __future__ import annotations

import copy
import math
import zlib
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..scene import DensityGrid, SourceInfo
from .limits import inflate_budget, require_input_file
from .ngp_cascades import (
    CascadeLayout,
    LatticeBox,
    cascade_mask,
    dense_to_morton,
    merge_cascades,
    morton_to_dense,
)
from .ngp_network import NetworkLayoutError, NgpNetwork, network_from_snapshot

__all__ = [
    "NgpFrame",
    "NgpSnapshot",
    "NgpGridSource",
    "NgpField",
    "NERF_GRIDSIZE",
    "STEPSIZE",
    "read_ngp_document",
    "parse_snapshot",
    "read_instant_ngp",
    "write_ngp_document",
    "write_masked_instant_ngp",
    "is_ngp_msgpack_head",
    "snapshot_occupancy",
    "MAX_CONE_STEPSIZE",
]

NERF_GRIDSIZE = 128
#: ``STEPSIZE()`` of ``nerf_device.cuh`` l. 29-33 (float32, as instant-ngp computes it)
STEPSIZE = float(np.float32(1.73205080757) / np.float32(1024))
NERF_CASCADES = 8
#: ``MAX_CONE_STEPSIZE()`` (``nerf_device.cuh`` l. 36)
MAX_CONE_STEPSIZE = STEPSIZE * (1 << (NERF_CASCADES - 1)) * 1024 / NERF_GRIDSIZE
SNAPSHOT_FORMAT_VERSION = 1


def is_ngp_msgpack_head(head: bytes) -> bool:
    """Whether ``head`` starts a msgpack map (what instant-ngp writes, after any gzip)."""
    return bool(head) and (0x80 <= head[0] <= 0x8F or head[0] in (0xDE, 0xDF))


@dataclass(frozen=True)
class NgpFrame:
    """instant-ngp's NeRF frame ↔ the training cameras' frame (module docstring)."""

    scale: float = 0.33
    offset: tuple[float, float, float] = (0.5, 0.5, 0.5)
    from_mitsuba: bool = False

    @property
    def axes(self) -> tuple[int, int, int]:
        """``axes[i]``: the training-frame axis that becomes NeRF-frame axis ``i``."""
        return (0, 1, 2) if self.from_mitsuba else (1, 2, 0)

    def to_ngp(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, np.float64)
        rv = p * self.scale + np.asarray(self.offset)
        return rv[..., list(self.axes)]

    def to_world(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, np.float64)
        rv = np.empty_like(q)
        rv[..., list(self.axes)] = q
        return (rv - np.asarray(self.offset)) / self.scale

    def dir_to_ngp(self, d: np.ndarray) -> np.ndarray:
        return np.asarray(d)[..., list(self.axes)]

    def lattice_to_density(self, lat: np.ndarray) -> np.ndarray:
        """NeRF-frame ``[x, y, z]`` lattice → training-frame ``[iz, iy, ix]`` array."""
        inv = np.argsort(self.axes)
        return np.ascontiguousarray(lat.transpose(tuple(inv)).transpose(2, 1, 0))

    def density_to_lattice(self, dens: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`lattice_to_density`."""
        return np.ascontiguousarray(dens.transpose(2, 1, 0).transpose(self.axes))


@dataclass(eq=False)
class NgpSnapshot:
    """A parsed snapshot.

    Attributes:
        document: the whole msgpack document (network config + ``snapshot``).
        cascades: ``[C, 128³]`` float16, Morton order (``density_grid_binary``).
        aabb_scale: ``nerf.aabb_scale``; frame: the dataset's scale, offset and axes.
        aabb: ``[2,3]`` instant-ngp's NeRF-frame box (the network's warp box).
        cameras: the snapshot's training cameras in the training frame (may be empty).
        network: the radiance network, or None (``network_note`` says why).
        compressed: the file was deflated (``.ingp``).
    """

    document: dict
    cascades: np.ndarray
    aabb_scale: int
    frame: NgpFrame
    aabb: np.ndarray
    cameras: list[Camera] = field(default_factory=list)
    network: NgpNetwork | None = None
    network_note: str = ""
    compressed: bool = True

    @property
    def layout(self) -> CascadeLayout:
        return CascadeLayout(len(self.cascades), NERF_GRIDSIZE, (0.5, 0.5, 0.5), 0.5)


@dataclass(eq=False)
class NgpField:
    """An instant-ngp radiance network with what marching it needs (``DensityGrid.network``
    of a snapshot read with its network; the renderer uses only these attributes)."""

    network: NgpNetwork
    snapshot: NgpSnapshot
    kind: str = "instant-ngp"

    @property
    def frame(self) -> tuple[float, np.ndarray, tuple[int, int, int]]:
        """``(scale, offset, axes)``: training frame → NeRF frame."""
        fr = self.snapshot.frame
        return fr.scale, np.asarray(fr.offset, np.float64), fr.axes

    @property
    def box(self) -> np.ndarray:
        return np.asarray(self.snapshot.aabb, np.float64)

    @property
    def n_cascades(self) -> int:
        return len(self.snapshot.cascades)

    @property
    def stepping(self) -> tuple[float, float, float]:
        """``(STEPSIZE, cone, MAX_CONE_STEPSIZE)``; cone stepping ``1/256`` for
        ``aabb_scale > 1``, as instant-ngp picks it (``testbed_nerf.cu`` l. 2438-2440)."""
        cone = 0.0 if self.snapshot.aabb_scale <= 1 else 1.0 / 256.0
        return STEPSIZE, cone, MAX_CONE_STEPSIZE

    def occupancy(self) -> np.ndarray:
        return snapshot_occupancy(self.snapshot)


@dataclass(eq=False)
class NgpGridSource:
    """What an export needs to write a masked snapshot of a loaded grid."""

    snapshot: NgpSnapshot
    box: LatticeBox


# ------------------------------------------------------------------------- reading
def _inflate(path: Path, raw: bytes) -> bytes:
    """gzip or zlib stream → bytes, at most the file's inflate budget."""
    budget = inflate_budget(len(raw))
    d = zlib.decompressobj(wbits=47)  # 32 + 15: gzip or zlib header, auto-detected
    out, total, data = [], 0, raw
    while data:
        chunk = d.decompress(data, max(1, budget + 1 - total))
        total += len(chunk)
        if total > budget:
            raise DivasInputError(
                path, f"inflates past the {budget}-byte limit for a file of this size (LoadLimits)"
            )
        out.append(chunk)
        data = d.unconsumed_tail
        if d.eof:
            break
    if not d.eof:
        raise DivasInputError(path, "truncated compressed stream")
    return b"".join(out)


def read_ngp_document(path: str | PathLike) -> tuple[dict, bool]:
    """The msgpack document of an ``.ingp``/``.msgpack`` file and whether it was deflated."""
    import msgpack

    path = require_input_file(path, "instant-ngp snapshot")
    raw = path.read_bytes()
    compressed = raw[:2] == b"\x1f\x8b" or (len(raw) > 1 and raw[0] == 0x78)
    data = _inflate(path, raw) if compressed else raw
    if not is_ngp_msgpack_head(data[:1]):
        raise DivasInputError(path, "not an instant-ngp snapshot (no msgpack map inside)")
    try:
        # every length msgpack declares is checked against the buffer it came from
        doc = msgpack.unpackb(data, raw=False, strict_map_key=False, use_list=True)
    except (ValueError, msgpack.UnpackException, msgpack.ExtraData, RecursionError) as e:
        raise DivasInputError(path, f"malformed msgpack ({type(e).__name__}: {e})") from None
    if not isinstance(doc, dict):
        raise DivasInputError(path, "not an instant-ngp snapshot (top level is not a map)")
    return doc, compressed


def _vec(v: Any, n: int, where: str, path: Path) -> np.ndarray:
    a = np.asarray(v, np.float64) if isinstance(v, list | tuple) else None
    if a is None or a.shape != (n,) or not np.all(np.isfinite(a)):
        raise DivasInputError(path, f"{where} must be {n} finite numbers, got {v!r:.80}")
    return a


def _binary(v: Any, dtype, where: str, path: Path) -> np.ndarray:
    if isinstance(v, dict) and "bytes" in v:  # nlohmann's JSON form of a binary value
        v = bytes(v["bytes"])
    if not isinstance(v, bytes | bytearray):
        raise DivasInputError(path, f"{where} is not binary data")
    if len(v) % np.dtype(dtype).itemsize:
        raise DivasInputError(path, f"{where}: {len(v)} bytes is not a whole number of values")
    return np.frombuffer(v, dtype)


def _cameras(ds: dict, frame: NgpFrame, path: Path) -> list[Camera]:
    xf, meta = ds.get("xforms") or [], ds.get("metadata") or []
    cams = []
    for i, x in enumerate(xf[: len(meta)]):
        m = meta[i] or {}
        try:
            M = np.asarray((x or {}).get("start"), np.float64)
            res = np.asarray(m["resolution"], np.float64)
            f = np.asarray(m["focal_length"], np.float64)
            pp = np.asarray(m.get("principal_point", [0.5, 0.5]), np.float64)
        except (KeyError, TypeError, ValueError):
            continue
        if M.shape != (3, 4) or res.shape != (2,) or f.shape != (2,) or pp.shape != (2,):
            continue
        if not (np.all(np.isfinite(M)) and np.all(res >= 1) and np.all(f > 0)):
            continue
        c2w = np.eye(4)
        ax = list(frame.axes)
        c2w[ax, :3] = M[:, :3]
        c2w[:3, 3] = frame.to_world(M[:, 3])
        if abs(np.linalg.det(c2w[:3, :3]) - 1.0) > 1e-2:
            continue
        paths = ds.get("paths") or []
        name = Path(str(paths[i])).stem if i < len(paths) and paths[i] else f"ngp_{i:04d}"
        w, h = int(res[0]), int(res[1])
        cams.append(Camera(w, h, f[0], f[1], pp[0] * w, pp[1] * h, c2w, name))
    return cams


def parse_snapshot(doc: dict, path: Path, compressed: bool = True) -> NgpSnapshot:
    """The fields this project reads, every size checked against what the file holds."""
    snap = doc.get("snapshot")
    if not isinstance(snap, dict):
        raise DivasInputError(path, "holds no 'snapshot' (a network config, not a snapshot)")
    mode = snap.get("mode", "Nerf" if "nerf" in snap else None)
    if str(mode) != "Nerf":
        raise DivasInputError(path, f"is an instant-ngp {mode} snapshot, not a NeRF")
    if int(snap.get("density_grid_size", NERF_GRIDSIZE)) != NERF_GRIDSIZE:
        raise DivasInputError(path, f"density_grid_size {snap.get('density_grid_size')} ≠ 128")
    nerf = snap.get("nerf") or {}
    ds = nerf.get("dataset") if isinstance(nerf.get("dataset"), dict) else {}
    aabb_scale = int(nerf.get("aabb_scale", ds.get("aabb_scale", 1)))
    if not 1 <= aabb_scale <= 1 << (NERF_CASCADES - 1):
        raise DivasInputError(path, f"aabb_scale {aabb_scale} outside 1…128")
    max_cascade = max(0, math.ceil(math.log2(aabb_scale)))
    n_cells = NERF_GRIDSIZE**3
    grid = _binary(snap.get("density_grid_binary"), "<f2", "density_grid_binary", path)
    if grid.size != n_cells * (max_cascade + 1):
        raise DivasInputError(
            path,
            f"density_grid_binary holds {grid.size} cells, aabb_scale {aabb_scale} needs "
            f"{max_cascade + 1} cascades of 128³ = {n_cells * (max_cascade + 1)}",
        )
    scale = float(ds.get("scale", 0.33))
    offset = _vec(ds.get("offset", [0.5, 0.5, 0.5]), 3, "nerf.dataset.offset", path)
    if not (math.isfinite(scale) and scale > 0):
        raise DivasInputError(path, f"nerf.dataset.scale must be > 0, got {scale}")
    frame = NgpFrame(scale, tuple(float(v) for v in offset), bool(ds.get("from_mitsuba", False)))
    half = 0.5 * min(1 << (NERF_CASCADES - 1), aabb_scale)  # testbed_nerf.cu l. 2424-2425
    box = snap.get("aabb") or {}
    if isinstance(box, dict) and "min" in box:
        aabb = np.stack(
            [_vec(box["min"], 3, "aabb.min", path), _vec(box["max"], 3, "aabb.max", path)]
        )
    else:
        aabb = np.array([[0.5 - half] * 3, [0.5 + half] * 3])
    if np.any(aabb[1] <= aabb[0]):
        raise DivasInputError(path, f"empty aabb {aabb.tolist()}")
    out = NgpSnapshot(
        doc,
        grid.reshape(max_cascade + 1, n_cells),
        aabb_scale,
        frame,
        aabb,
        _cameras(ds, frame, path),
        compressed=compressed,
    )
    out.network, out.network_note = _network(doc, snap, ds, out, path)
    return out


def _network(doc, snap, ds, out: NgpSnapshot, path: Path) -> tuple[NgpNetwork | None, str]:
    if "params_binary" not in snap:
        return None, "the snapshot holds no network parameters"
    ptype = str(snap.get("params_type", "__half"))
    if ptype not in ("__half", "float"):
        return None, f"params_type {ptype!r} is neither __half nor float"
    params = _binary(snap["params_binary"], "<f2" if ptype == "__half" else "<f4", "params", path)
    try:
        net = network_from_snapshot(
            doc,
            params,
            out.aabb,
            out.aabb_scale,
            int(ds.get("n_extra_learnable_dims", 0)),
            bool(ds.get("is_hdr", False)),
        )
    except NetworkLayoutError as e:
        return None, f"network not read: {e}"
    return net, ""


def snapshot_occupancy(snap: NgpSnapshot) -> np.ndarray:
    """``[8, 128, 128, 128]`` bool, ``[m, x, y, z]``: instant-ngp's bitfield — cells above
    ``min(0.01, mean of cascade 0)`` (``grid_to_bitfield``) in the snapshot's cascades, and
    every level OR-ed with the level below max-pooled into its central half
    (``bitfield_max_pool``, l. 376-396), up to ``NERF_CASCADES`` levels: the march skips
    empty space through all of them."""
    dense = morton_to_dense(snap.cascades, NERF_GRIDSIZE).astype(np.float32)
    dense[~np.isfinite(dense)] = 0.0
    R, q = NERF_GRIDSIZE, NERF_GRIDSIZE // 4
    occ = np.zeros((NERF_CASCADES, R, R, R), bool)
    occ[: len(dense)] = dense > min(0.01, float(np.maximum(dense[0], 0).mean()))
    for m in range(1, NERF_CASCADES):
        pooled = occ[m - 1].reshape(R // 2, 2, R // 2, 2, R // 2, 2).any(axis=(1, 3, 5))
        occ[m, q : R - q, q : R - q, q : R - q] |= pooled
    return occ


def _lattice(snap: NgpSnapshot, max_side: int) -> tuple[np.ndarray, LatticeBox]:
    """σ per NeRF-frame unit on one lattice, instant-ngp's empty cells zeroed."""
    dense = morton_to_dense(snap.cascades, NERF_GRIDSIZE).astype(np.float32)
    dense[~np.isfinite(dense)] = 0.0
    mean0 = float(np.maximum(dense[0], 0).mean())
    thresh = min(0.01, mean0)
    occupied = dense > thresh
    dense[~occupied] = 0.0
    lat, box = merge_cascades(dense, snap.layout, occupied, max_side)
    return lat / np.float32(STEPSIZE), box


def snapshot_grid(snap: NgpSnapshot, path: Path, fmt: str, max_side: int = 256) -> DensityGrid:
    """The snapshot's density on one lattice in the training cameras' frame."""
    lat, box = _lattice(snap, max_side)
    if not np.any(lat > 0):
        raise DivasInputError(path, "empty scene: every density-grid cell is empty")
    fr = snap.frame
    density = fr.lattice_to_density(lat * np.float32(fr.scale))
    corners = np.stack([fr.to_world(box.lo), fr.to_world(box.hi)])
    aabb = np.stack([corners.min(0), corners.max(0)])
    src = SourceInfo(path, fmt, int(density.size), None, 0)
    field = NgpField(snap.network, snap) if snap.network is not None else None
    grid = DensityGrid(density, aabb, None, src, network=field)
    grid.extras.update(
        ngp=NgpGridSource(snap, box),
        cameras=snap.cameras,
        network_note=snap.network_note,
        aabb_scale=snap.aabb_scale,
        cascades=len(snap.cascades),
    )
    return grid


def read_instant_ngp(path: str | PathLike, max_side: int = 256) -> DensityGrid:
    """Load an ``.ingp``/``.msgpack`` snapshot as a :class:`DensityGrid` (module docstring).

    The grid keeps the network (``grid.network``) and the snapshot (``grid.extras``:
    ``ngp``, ``cameras``) so views can be rendered from the network and exports write a
    masked snapshot.
    """
    path = require_input_file(path, "instant-ngp snapshot")
    doc, compressed = read_ngp_document(path)
    snap = parse_snapshot(doc, path, compressed)
    return snapshot_grid(snap, path, "ingp" if compressed else "msgpack", max_side)


# ------------------------------------------------------------------------- writing
def _sorted(v: Any) -> Any:
    """Maps with sorted keys, as nlohmann::json (a std::map) serialises them."""
    if isinstance(v, dict):
        return {k: _sorted(v[k]) for k in sorted(v)}
    if isinstance(v, list):
        return [_sorted(x) for x in v]
    return v


def write_ngp_document(path: str | PathLike, doc: dict, compressed: bool) -> Path:
    """Write ``doc`` as instant-ngp does: msgpack, deflated in gzip when ``compressed``."""
    import gzip

    import msgpack

    from ..output_paths import write_bytes_atomic

    data = msgpack.packb(_sorted(doc), use_bin_type=True)
    if compressed:
        data = gzip.compress(data, compresslevel=6, mtime=0)
    return write_bytes_atomic(path, data)


def write_masked_instant_ngp(
    grid: DensityGrid, selection: np.ndarray, path: str | PathLike
) -> Path:
    """The source snapshot with every positive density-grid cell that no selected voxel
    overlaps set to 0 (instant-ngp then renders the selected part alone); everything else
    unchanged, so a selection of every voxel writes the grid back bit for bit."""
    src = grid.extras.get("ngp")
    if not isinstance(src, NgpGridSource):
        raise DivasInputError(path, "this grid was not read from an instant-ngp snapshot")
    snap = src.snapshot
    sel = snap.frame.density_to_lattice(np.asarray(selection, bool))
    keep = dense_to_morton(cascade_mask(sel, snap.layout, src.box))
    raw = snap.cascades
    # positive cells no selected voxel overlaps become 0; unseen (−1) and 0 cells stay
    masked = np.where(keep | ~(raw > 0), raw, np.float16(0)).astype("<f2")
    doc = copy.copy(snap.document)
    doc["snapshot"] = dict(doc["snapshot"])
    doc["snapshot"]["density_grid_binary"] = masked.tobytes()
    return write_ngp_document(path, doc, snap.compressed)
