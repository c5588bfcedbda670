"""Write a dense grid as an OpenVDB ``.vdb`` file in NumPy, without an OpenVDB module.

For Blenders whose Python has no OpenVDB module (the ``bpy`` 4.2 wheel): Blender's own
C++ reader builds Volume objects from these files. The layout is OpenVDB's file format
version 224 (``io::Archive`` with grid offsets, ``GridDescriptor``, ``ScaleTranslateMap``
and the ``Tree_<type>_5_4_3`` tree) with no compression, so each part is plain bytes; every
voxel lives in a leaf, active where its value is nonzero (a fog volume: background 0).
Byte layout in full: docs/design-notes.md.
"""

from __future__ import annotations

import struct
import uuid
from os import PathLike
from pathlib import Path

import numpy as np

__all__ = ["write_vdb_numpy"]

FILE_VERSION = 224
LIBRARY = (11, 0)
_TYPES = {1: ("Tree_float_5_4_3", "<f4"), 3: ("Tree_vec3s_5_4_3", "<f4")}


def _text(s: str) -> bytes:
    b = s.encode("utf-8")
    return struct.pack("<I", len(b)) + b


def _meta(entries: dict[str, str | tuple[int, int, int]]) -> bytes:
    """A ``MetaMap``: strings, and integer triples as ``vec3i``."""
    out = [struct.pack("<i", len(entries))]
    for k, v in entries.items():
        kind, b = ("string", v.encode("utf-8")) if isinstance(v, str) else ("vec3i", None)
        if b is None:
            b = struct.pack("<3i", *(int(c) for c in v))
        out += [_text(k), _text(kind), struct.pack("<i", len(b)), b]
    return b"".join(out)


def _mask(bits: np.ndarray) -> bytes:
    """A node mask: ``bits`` (x-major, a multiple of 64) as little-endian 64-bit words."""
    return np.packbits(bits.astype(np.uint8), bitorder="little").tobytes()


def _scale_translate(origin: np.ndarray, vox: np.ndarray) -> bytes:
    """``ScaleTranslateMap``: translation, scale, voxel size, 1/scale, 1/scale², 1/(2·scale)."""
    v = np.asarray(vox, np.float64)
    parts = (origin, v, v, 1.0 / v, 1.0 / (v * v), 0.5 / v)
    return _text("ScaleTranslateMap") + np.concatenate(parts).astype("<f8").tobytes()


def _tree(values: np.ndarray) -> tuple[bytes, bytes]:
    """Topology and buffers of ``values`` (``[X, Y, Z]`` or ``[X, Y, Z, C]``, index space
    from the origin) as a 5-4-3 tree."""
    C = 1 if values.ndim == 3 else values.shape[3]
    vals = values.reshape(values.shape[:3] + (C,)).astype("<f4")
    active = np.any(vals != 0, axis=3)
    X, Y, Z = active.shape
    pad = [(0, (-n) % 8) for n in (X, Y, Z)]
    act = np.pad(active, pad)
    v = np.pad(vals, pad + [(0, 0)])
    nb = np.array(act.shape) // 8
    blocks = act.reshape(nb[0], 8, nb[1], 8, nb[2], 8).any(axis=(1, 3, 5))
    leaves = np.argwhere(blocks)  # leaf indices, x-major (ascending offsets)
    zero = struct.pack("<" + "f" * C, *([0.0] * C))
    root_children = sorted({tuple(int(c) for c in lf // 512) for lf in leaves})
    topo = [struct.pack("<i", 1), zero, struct.pack("<II", 0, len(root_children))]
    bufs = []
    for rc in root_children:
        in_root = leaves[np.all(leaves // 512 == rc, axis=1)]
        topo.append(struct.pack("<3i", *(int(c) * 4096 for c in rc)))
        n4 = sorted({tuple(int(c) for c in lf // 16) for lf in in_root})
        m5 = np.zeros(32**3, bool)
        for c in n4:
            a = np.asarray(c) % 32
            m5[(a[0] * 32 + a[1]) * 32 + a[2]] = True
        topo += [_mask(m5), _mask(np.zeros(32**3, bool)), b"\x06", zero * 32**3]
        order4 = sorted(n4, key=lambda c: tuple(np.asarray(c) % 32))
        for c4 in order4:
            in4 = in_root[np.all(in_root // 16 == c4, axis=1)]
            m4 = np.zeros(16**3, bool)
            a = in4 % 16
            m4[(a[:, 0] * 16 + a[:, 1]) * 16 + a[:, 2]] = True
            topo += [_mask(m4), _mask(np.zeros(16**3, bool)), b"\x06", zero * 16**3]
            key = (a[:, 0] * 16 + a[:, 1]) * 16 + a[:, 2]
            for lf in in4[np.argsort(key)]:
                x, y, z = (int(c) * 8 for c in lf)
                m = _mask(act[x : x + 8, y : y + 8, z : z + 8].ravel())
                topo.append(m)
                data = v[x : x + 8, y : y + 8, z : z + 8].reshape(512, C)
                bufs += [m, b"\x06", np.ascontiguousarray(data).tobytes()]
    return b"".join(topo), b"".join(bufs)


def write_vdb_numpy(
    path: str | PathLike,
    grids: list[tuple[str, np.ndarray]],
    origin: np.ndarray,
    voxel: np.ndarray,
    metadata: dict[str, dict] | None = None,
) -> Path:
    """Write ``grids`` (``(name, values)``, values ``[X, Y, Z]`` float or ``[X, Y, Z, 3]``
    vectors, voxel ``(i, j, k)`` centred at ``origin + (i, j, k)·voxel``) to ``path``;
    ``metadata[name]``: more entries of that grid's metadata (strings, integer triples)."""
    out = bytearray()
    out += struct.pack("<qIIIb", 0x56444220, FILE_VERSION, *LIBRARY, 1)
    out += str(uuid.uuid4()).upper().encode("ascii")
    out += _meta({}) + struct.pack("<i", len(grids))
    xform = _scale_translate(np.asarray(origin, np.float64), np.asarray(voxel, np.float64))
    for name, values in grids:
        values = np.asarray(values, np.float32)
        tree_type = _TYPES[1 if values.ndim == 3 else values.shape[3]][0]
        out += _text(name) + _text(tree_type) + _text("")
        at = len(out)
        out += bytes(24)  # grid, buffers and end positions, filled in below
        grid_pos = len(out)
        meta = {"class": "fog volume" if values.ndim == 3 else "unknown", "name": name}
        meta.update((metadata or {}).get(name, {}))
        out += struct.pack("<I", 0) + _meta(meta) + xform
        topo, bufs = _tree(values)
        out += topo
        block_pos = len(out)
        out += bufs
        struct.pack_into("<qqq", out, at, grid_pos, block_pos, len(out))
    path = Path(path)
    path.write_bytes(bytes(out))
    return path
