"""Exact row subsets of an existing PLY file: every property, original order and types.

The output is binary little-endian whatever the input was (ASCII or big-endian
inputs are converted value-for-value), so it opens wherever the input opened.
Non-vertex elements are copied unchanged; comments and obj_info are kept.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
import plyfile

from ..errors import DivasInputError
from .ply import iter_vertex_chunks, read_ply_header

__all__ = ["write_ply_subset"]

_PLY_TYPE = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
             "u4": "uint", "f4": "float", "f8": "double"}


def _header(layout, counts: dict[str, int]) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in layout.ply.comments]
    lines += [f"obj_info {c}" for c in layout.ply.obj_info]
    for e in layout.elements:
        lines.append(f"element {e.name} {counts.get(e.name, e.count)}")
        for p in e.properties:
            if isinstance(p, plyfile.PlyListProperty):
                raise DivasInputError(layout.path, f"list property {p.name!r} cannot be subset")
            lines.append(f"property {_PLY_TYPE[np.dtype(p.val_dtype).str[1:]]} {p.name}")
    return ("\n".join(lines) + "\nend_header\n").encode("ascii")


def write_ply_subset(src: str | PathLike, file_rows: np.ndarray, out: str | PathLike) -> int:
    """Write the vertex rows ``file_rows`` (ascending file indices) of ``src`` to ``out``.

    Returns the number of rows written. Reads ``src`` in chunks, so memory stays
    bounded for multi-million-row files.
    """
    src, out = Path(src), Path(out)
    layout = read_ply_header(src)
    rows = np.asarray(file_rows, dtype=np.int64)
    if rows.size and (np.any(np.diff(rows) <= 0) or rows[0] < 0 or rows[-1] >= layout.vertex.count):
        raise ValueError("file_rows must be strictly increasing indices into the vertex element")
    other = [e for e in layout.elements if e.name != "vertex"]
    other_data = {}
    if other:
        full = plyfile.PlyData.read(str(src))
        other_data = {e.name: full[e.name].data for e in other}
    le = np.dtype([(n, layout.vertex_dtype()[n].newbyteorder("<"))
                   for n in layout.vertex_dtype().names])
    with open(out, "wb") as f:
        f.write(_header(layout, {"vertex": len(rows)}))
        for e in layout.elements:
            if e.name != "vertex":
                d = other_data[e.name]
                np.asarray(d, dtype=[(n, d.dtype[n].newbyteorder("<")) for n in d.dtype.names]).tofile(f)
                continue
            for start, chunk in iter_vertex_chunks(layout):
                lo, hi = np.searchsorted(rows, [start, start + len(chunk)])
                if hi > lo:
                    np.asarray(chunk[rows[lo:hi] - start], dtype=le).tofile(f)
    return len(rows)
