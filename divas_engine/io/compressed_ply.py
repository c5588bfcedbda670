"""PlayCanvas / SuperSplat *compressed PLY*: decoder and re-encoding subset writer.

Per run of 256 splats an ``element chunk`` row of float bounds (position, log-scale and, in newer
files, colour); per splat four ``uint`` words: position and scale as 11/10/11-bit unorms lerped
between the chunk bounds, rotation as "smallest three" (2-bit index, three 10-bit components),
colour as RGBA bytes (alpha = activated opacity); an optional ``element sh`` of ``uchar``
``f_rest`` dequantised to the bucket centre as ``splat-transform``'s reader does. Coordinates
are the source 3DGS PLY's (no axis change).

A subset cannot be cut out byte-exactly (chunk membership is positional), so
:func:`write_compressed_ply_subset` re-encodes the selected splats with fresh per-chunk bounds
by the writer's rules; the chunk-independent fields (rotation word, alpha byte, ``sh`` bytes)
are copied verbatim. Bit layouts in full: docs/design-notes.md.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
import plyfile

from ..errors import DivasInputError
from ..kinds import SceneKind
from ..output_paths import same_file
from ..scene import SH_C0, SourceInfo, SurfelScene, sh_coeff_count
from .gaussians import check_file_rows, scene_from_rows, surfels_from_arrays
from .ply import CHUNK_ROWS, PlyLayout, read_ply_header, write_ply_rows

__all__ = [
    "is_compressed_ply",
    "read_compressed_ply",
    "write_compressed_ply_subset",
    "decode_compressed_ply_rows",
    "SPLATS_PER_CHUNK",
]

#: Splats that share one row of chunk bounds.
SPLATS_PER_CHUNK = 256

_CHUNK_BASE = (
    "min_x",
    "min_y",
    "min_z",
    "max_x",
    "max_y",
    "max_z",
    "min_scale_x",
    "min_scale_y",
    "min_scale_z",
    "max_scale_x",
    "max_scale_y",
    "max_scale_z",
)
_CHUNK_COLOR = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
_PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
_SQRT2 = np.sqrt(2.0)
#: For each largest-component index L, the other three indices in ascending order.
_OTHERS = np.array([[i for i in range(4) if i != big] for big in range(4)], dtype=np.int64)


def is_compressed_ply(layout: PlyLayout) -> bool:
    """True when the header has an element ``chunk`` and vertex ``packed_position``."""
    if layout.element("chunk") is None:
        return False
    v = layout.element("vertex")
    return v is not None and any(p.name == "packed_position" for p in v.properties)


class _Layout:
    """Validated byte layout of a compressed PLY body."""

    def __init__(self, layout: PlyLayout):
        path = self.path = layout.path
        if layout.text:
            raise DivasInputError(path, "compressed PLY must be binary, not ASCII")
        offsets: dict[str, int] = {}
        off = layout.data_offset
        for e in layout.elements:
            if any(isinstance(p, plyfile.PlyListProperty) for p in e.properties):
                raise DivasInputError(
                    path,
                    f"compressed PLY element '{e.name}' has list "
                    "properties; expected fixed-size rows",
                )
            offsets[e.name] = off
            off += e.count * np.dtype(e.dtype(layout.byte_order)).itemsize
        chunk, vertex = layout.element("chunk"), layout.element("vertex")
        if chunk is None or vertex is None:
            raise DivasInputError(path, "compressed PLY needs elements 'chunk' and 'vertex'")
        self.chunk_dtype = np.dtype(chunk.dtype(layout.byte_order))
        self.vertex_dtype = np.dtype(vertex.dtype(layout.byte_order))
        names = set(self.chunk_dtype.names)
        missing = [p for p in _CHUNK_BASE if p not in names]
        if missing:
            raise DivasInputError(path, f"compressed PLY chunk element lacks {missing}")
        self.has_color = all(p in names for p in _CHUNK_COLOR)
        for p in _CHUNK_BASE + (_CHUNK_COLOR if self.has_color else ()):
            if self.chunk_dtype[p].kind != "f":
                raise DivasInputError(path, f"compressed PLY chunk property {p} must be float")
        for p in _PACKED:
            if p not in self.vertex_dtype.names:
                raise DivasInputError(path, f"compressed PLY vertex element lacks '{p}'")
            if self.vertex_dtype[p].kind != "u" or self.vertex_dtype[p].itemsize != 4:
                raise DivasInputError(path, f"compressed PLY property {p} must be uint32")
        self.n = vertex.count
        self.n_chunks = chunk.count
        if self.n == 0:
            raise DivasInputError(path, "empty scene: the compressed PLY has 0 vertices")
        expect = -(-self.n // SPLATS_PER_CHUNK)
        if self.n_chunks != expect:
            raise DivasInputError(
                path,
                f"compressed PLY has {self.n_chunks} chunks for "
                f"{self.n} splats; expected {expect} (256 per chunk)",
            )
        self.chunk_off = offsets["chunk"]
        self.vertex_off = offsets["vertex"]
        sh = layout.element("sh")
        self.sh_dtype = None
        self.sh_off = 0
        self.sh_names: list[str] = []
        self.sh_degree = 0
        if sh is not None:
            dt = np.dtype(sh.dtype(layout.byte_order))
            n_rest = len(dt.names)
            degs = {3 * (sh_coeff_count(d) - 1): d for d in (1, 2, 3)}
            if n_rest not in degs:
                raise DivasInputError(
                    path,
                    f"compressed PLY 'sh' element has {n_rest} properties; expected 9, 24 or 45",
                )
            want = [f"f_rest_{i}" for i in range(n_rest)]
            if set(dt.names) != set(want) or any(dt[nm] != np.dtype("u1") for nm in want):
                raise DivasInputError(
                    path, f"compressed PLY 'sh' element must hold uchar f_rest_0..{n_rest - 1}"
                )
            if sh.count != self.n:
                raise DivasInputError(
                    path, f"compressed PLY 'sh' element has {sh.count} rows for {self.n} vertices"
                )
            self.sh_dtype, self.sh_off, self.sh_names = dt, offsets["sh"], want
            self.sh_degree = degs[n_rest]
        size = Path(path).stat().st_size
        if size < off:
            raise DivasInputError(
                path, f"truncated compressed PLY: header promises {off} bytes, file has {size}"
            )

    def read_chunks(self) -> dict[str, np.ndarray | None]:
        c = np.fromfile(
            self.path, dtype=self.chunk_dtype, count=self.n_chunks, offset=self.chunk_off
        )
        if len(c) != self.n_chunks:
            raise DivasInputError(self.path, "truncated compressed PLY chunk data")

        def cols(*names: str) -> np.ndarray:
            return np.stack([c[nm].astype(np.float64) for nm in names], axis=1)

        out = {
            "pmin": cols("min_x", "min_y", "min_z"),
            "pmax": cols("max_x", "max_y", "max_z"),
            "smin": cols("min_scale_x", "min_scale_y", "min_scale_z"),
            "smax": cols("max_scale_x", "max_scale_y", "max_scale_z"),
            "cmin": None,
            "cmax": None,
        }
        if self.has_color:
            out["cmin"] = cols("min_r", "min_g", "min_b")
            out["cmax"] = cols("max_r", "max_g", "max_b")
        return out

    def vertex_memmap(self) -> np.memmap:
        return np.memmap(
            self.path, dtype=self.vertex_dtype, mode="r", offset=self.vertex_off, shape=(self.n,)
        )

    def sh_memmap(self) -> np.memmap | None:
        if self.sh_dtype is None:
            return None
        return np.memmap(
            self.path, dtype=self.sh_dtype, mode="r", offset=self.sh_off, shape=(self.n,)
        )


def _unorm(word: np.ndarray, shift: int, bits: int) -> np.ndarray:
    mask = (1 << bits) - 1
    return ((word >> np.uint32(shift)) & np.uint32(mask)).astype(np.float64) / mask


def _unpack_111011(word: np.ndarray) -> np.ndarray:
    return np.stack([_unorm(word, 21, 11), _unorm(word, 11, 10), _unorm(word, 0, 11)], axis=1)


def _lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
    return lo * (1.0 - t) + hi * t


def _unpack_rotation(word: np.ndarray) -> np.ndarray:
    """``[n,4]`` float64 quaternions (w, x, y, z) from ``packed_rotation`` words."""
    n = len(word)
    small = np.stack(
        [
            (_unorm(word, 20, 10) - 0.5) * _SQRT2,
            (_unorm(word, 10, 10) - 0.5) * _SQRT2,
            (_unorm(word, 0, 10) - 0.5) * _SQRT2,
        ],
        axis=1,
    )
    big = (word >> np.uint32(30)).astype(np.int64)
    q = np.empty((n, 4), np.float64)
    rows = np.arange(n)
    q[rows, big] = np.sqrt(np.maximum(0.0, 1.0 - np.sum(small * small, axis=1)))
    others = _OTHERS[big]
    for j in range(3):
        q[rows, others[:, j]] = small[:, j]
    return q


def _decode_fields(packed: np.ndarray, chunk_idx: np.ndarray, ch: dict) -> dict[str, np.ndarray]:
    """Stored-space values of vertex rows (float64), given each row's chunk index."""
    pos = _lerp(
        ch["pmin"][chunk_idx], ch["pmax"][chunk_idx], _unpack_111011(packed["packed_position"])
    )
    log_s = _lerp(
        ch["smin"][chunk_idx], ch["smax"][chunk_idx], _unpack_111011(packed["packed_scale"])
    )
    cw = packed["packed_color"]
    rgb = np.stack([_unorm(cw, 24, 8), _unorm(cw, 16, 8), _unorm(cw, 8, 8)], axis=1)
    if ch["cmin"] is not None:
        rgb = _lerp(ch["cmin"][chunk_idx], ch["cmax"][chunk_idx], rgb)
    return {
        "pos": pos,
        "log_scale": log_s,
        "rgb": rgb,
        "alpha": _unorm(cw, 0, 8),
        "quat": _unpack_rotation(packed["packed_rotation"]),
    }


def _dequantize_sh(sh_rows: np.ndarray, names: list[str]) -> np.ndarray:
    """``[n, 3(K-1)]`` float32 f_rest values from the uchar ``sh`` rows."""
    b = np.stack([sh_rows[nm] for nm in names], axis=1).astype(np.float32)
    v = ((b + 0.5) / 256.0 - 0.5) * 8.0
    v[b == 0] = -4.0
    v[b == 255] = 4.0
    return v


def decode_compressed_ply_rows(
    path: str | PathLike, rows: np.ndarray | None = None, layout: PlyLayout | None = None
) -> dict[str, np.ndarray]:
    """Stored-space values of some (or all) rows, for tests and tools.

    Returns float64 ``pos [n,3]``, ``log_scale [n,3]``, ``rgb [n,3]`` (colour space),
    ``alpha [n]`` (activated opacity), ``quat [n,4]`` (w, x, y, z) and float32
    ``f_rest [n, 3(K-1)]`` (channel-major; zero columns without an ``sh`` element).
    """
    cl = _Layout(layout or read_ply_header(path))
    rows = np.arange(cl.n) if rows is None else check_file_rows(cl.path, rows, cl.n)
    ch = cl.read_chunks()
    out = _decode_fields(np.asarray(cl.vertex_memmap()[rows]), rows // SPLATS_PER_CHUNK, ch)
    shm = cl.sh_memmap()
    out["f_rest"] = (
        np.zeros((len(rows), 0), np.float32)
        if shm is None
        else _dequantize_sh(np.asarray(shm[rows]), cl.sh_names)
    )
    return out


def read_compressed_ply(path: str | PathLike, layout: PlyLayout | None = None) -> SurfelScene:
    """Load a compressed PLY into a :class:`SurfelScene` (3DGS flattened to surfels).

    Rows whose position, scale or colour decode to NaN/Inf (from non-finite chunk
    bounds) are dropped and counted in ``scene.source.dropped_nonfinite``.
    """
    path = Path(path)
    layout = layout or read_ply_header(path)
    cl = _Layout(layout)
    total, deg = cl.n, cl.sh_degree
    k = sh_coeff_count(deg)
    ch = cl.read_chunks()
    vmm, shm = cl.vertex_memmap(), cl.sh_memmap()

    means = np.empty((total, 3), np.float32)
    quats = np.empty((total, 4), np.float32)
    scales = np.empty((total, 2), np.float32)
    scale_n = np.empty(total, np.float32)
    opac = np.empty(total, np.float32)
    sh = np.empty((total, k, 3), np.float32)
    finite = np.empty(total, bool)
    for start in range(0, total, CHUNK_ROWS):  # CHUNK_ROWS is a multiple of 256
        stop = min(total, start + CHUNK_ROWS)
        sl = slice(start, stop)
        rows = np.arange(start, stop)
        f = _decode_fields(np.asarray(vmm[sl]), rows // SPLATS_PER_CHUNK, ch)
        ok = (
            np.isfinite(f["pos"]).all(1)
            & np.isfinite(f["log_scale"]).all(1)
            & np.isfinite(f["rgb"]).all(1)
        )
        with np.errstate(over="ignore", invalid="ignore"):
            s_act = np.exp(np.clip(f["log_scale"], -80.0, 80.0)).astype(np.float32)
        s_act = np.where(ok[:, None], s_act, np.float32(1.0))
        q2, s2 = surfels_from_arrays(f["quat"].astype(np.float32), s_act)
        scale_n[sl] = s_act.min(1)
        means[sl] = f["pos"]
        quats[sl], scales[sl] = q2, s2
        opac[sl] = f["alpha"]
        with np.errstate(over="ignore", invalid="ignore"):  # ±inf rows are dropped below
            sh[sl, 0, :] = (f["rgb"] - 0.5) / SH_C0
        if deg:
            rest = _dequantize_sh(np.asarray(shm[sl]), cl.sh_names)
            sh[sl, 1:, :] = rest.reshape(-1, 3, k - 1).transpose(0, 2, 1)
        finite[sl] = ok

    return scene_from_rows(
        path,
        "compressed_ply",
        (means, quats, scales, opac, sh),
        finite,
        deg,
        SceneKind.GS3D,
        scale_n=scale_n,
    )


def _chunk_bounds(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-256 min/max of ``v [n,3]``; the last chunk is padded with its last row."""
    n = len(v)
    c = -(-n // SPLATS_PER_CHUNK)
    pad = np.concatenate([np.arange(n), np.full(c * SPLATS_PER_CHUNK - n, n - 1)])
    blocks = v[pad].reshape(c, SPLATS_PER_CHUNK, 3)
    return blocks.min(axis=1), blocks.max(axis=1)


def _normalize(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The writer's ``normalize``: 0 at/below min, 1 at/above max, 0 for a range < 1e-5."""
    lo, hi = lo.astype(np.float64), hi.astype(np.float64)
    rng = hi - lo
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(rng < 1e-5, 0.0, (x - lo) / np.where(rng > 0, rng, 1.0))
    t = np.where(x >= hi, 1.0, t)
    return np.where(x <= lo, 0.0, t)


def _pack_unorm(t: np.ndarray, bits: int) -> np.ndarray:
    m = (1 << bits) - 1
    return np.clip(np.floor(t * m + 0.5), 0, m).astype(np.uint32)


def _pack_111011(t: np.ndarray) -> np.ndarray:
    return (
        (_pack_unorm(t[:, 0], 11) << np.uint32(21))
        | (_pack_unorm(t[:, 1], 10) << np.uint32(11))
        | _pack_unorm(t[:, 2], 11)
    )


def write_compressed_ply_subset(
    source: SourceInfo, file_rows: np.ndarray, out_path: str | PathLike
) -> None:
    """Write rows ``file_rows`` (in that order) of a compressed PLY as a new one.

    Positions, log-scales and (with colour bounds) colours are re-encoded against
    fresh chunk bounds of the selection; rotation words, alpha bytes and ``sh``
    bytes are copied unchanged. Each re-encoded value is within half a
    quantisation step of the fresh chunk range of the value decoded from the source.
    """
    path = Path(source.path)
    if same_file(path, out_path):
        raise DivasInputError(out_path, "the output is the input; refusing to overwrite the input")
    layout = read_ply_header(path)
    if not is_compressed_ply(layout):
        raise DivasInputError(path, "not a compressed PLY (no 'chunk' element / packed_position)")
    cl = _Layout(layout)
    rows = check_file_rows(path, file_rows, cl.n)
    if rows.size == 0:
        raise ValueError("nothing to write: file_rows is empty")
    packed = np.asarray(cl.vertex_memmap()[rows])
    f = _decode_fields(packed, rows // SPLATS_PER_CHUNK, cl.read_chunks())

    pos = f["pos"].astype(np.float32).astype(np.float64)
    log_s = f["log_scale"].astype(np.float32).astype(np.float64)
    pmin, pmax = _chunk_bounds(pos)
    smin, smax = (np.clip(b, -20.0, 20.0) for b in _chunk_bounds(log_s))
    n_out = len(rows)
    ci = np.arange(n_out) // SPLATS_PER_CHUNK
    out_v = np.empty(n_out, dtype=[(p, "<u4") for p in _PACKED])
    out_v["packed_position"] = _pack_111011(_normalize(pos, pmin[ci], pmax[ci]))
    out_v["packed_scale"] = _pack_111011(_normalize(log_s, smin[ci], smax[ci]))
    out_v["packed_rotation"] = packed["packed_rotation"]
    names = list(_CHUNK_BASE)
    bounds = [pmin, pmax, smin, smax]
    cw = packed["packed_color"].astype(np.uint32)
    if cl.has_color:
        rgb = f["rgb"].astype(np.float32).astype(np.float64)
        cmin, cmax = _chunk_bounds(rgb)
        t = _normalize(rgb, cmin[ci], cmax[ci])
        out_v["packed_color"] = (
            (_pack_unorm(t[:, 0], 8) << np.uint32(24))
            | (_pack_unorm(t[:, 1], 8) << np.uint32(16))
            | (_pack_unorm(t[:, 2], 8) << np.uint32(8))
            | (cw & np.uint32(0xFF))
        )
        names += list(_CHUNK_COLOR)
        bounds += [cmin, cmax]
    else:
        out_v["packed_color"] = cw
    cb = np.concatenate(bounds, axis=1).astype(np.float32)
    out_c = np.empty(len(cb), dtype=[(nm, "<f4") for nm in names])
    for j, nm in enumerate(names):
        out_c[nm] = cb[:, j]
    elements = {"chunk": out_c, "vertex": out_v}
    shm = cl.sh_memmap()
    if shm is not None:
        src_sh = np.asarray(shm[rows])
        out_sh = np.empty(n_out, dtype=[(nm, "u1") for nm in cl.sh_names])
        for nm in cl.sh_names:
            out_sh[nm] = src_sh[nm]
        elements["sh"] = out_sh
    write_ply_rows(out_path, elements, comments=["divas_engine subset of a compressed PLY"])
