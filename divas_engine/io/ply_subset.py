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
from ..output_paths import atomic_file, same_file
from .ply import iter_vertex_chunks, read_ply_header

__all__ = ["write_ply_subset"]

_PLY_TYPE = {
    "i1": "char",
    "u1": "uchar",
    "i2": "short",
    "u2": "ushort",
    "i4": "int",
    "u4": "uint",
    "f4": "float",
    "f8": "double",
}


def _header(layout, counts: dict[str, int], extra: dict[str, np.dtype]) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in layout.ply.comments]
    lines += [f"obj_info {c}" for c in layout.ply.obj_info]
    for e in layout.elements:
        lines.append(f"element {e.name} {counts.get(e.name, e.count)}")
        for p in e.properties:
            if isinstance(p, plyfile.PlyListProperty):
                raise DivasInputError(layout.path, f"list property {p.name!r} cannot be subset")
            lines.append(f"property {_PLY_TYPE[np.dtype(p.val_dtype).str[1:]]} {p.name}")
        if e.name == "vertex":
            lines += [f"property {_PLY_TYPE[dt.str[1:]]} {name}" for name, dt in extra.items()]
    return ("\n".join(lines) + "\nend_header\n").encode("ascii")


def write_ply_subset(
    src: str | PathLike,
    file_rows: np.ndarray | None,
    out: str | PathLike,
    *,
    extra_columns: dict[str, np.ndarray] | None = None,
) -> int:
    """Write the vertex rows ``file_rows`` (ascending file indices; None = all) of ``src``
    to ``out``, optionally with extra per-row vertex properties appended after the
    original ones (``extra_columns``: name → ``[num_rows]`` array over the *file* rows).

    Returns the number of rows written. Reads ``src`` in chunks, so memory stays
    bounded for multi-million-row files.
    """
    src, out = Path(src), Path(out)
    if same_file(src, out):
        raise DivasInputError(out, "the output is the input PLY; refusing to overwrite the input")
    layout = read_ply_header(src)
    n_file = layout.vertex.count
    rows = (
        np.arange(n_file, dtype=np.int64) if file_rows is None else np.asarray(file_rows, np.int64)
    )
    if rows.size and (np.any(np.diff(rows) <= 0) or rows[0] < 0 or rows[-1] >= n_file):
        raise ValueError("file_rows must be strictly increasing indices into the vertex element")
    extra = {k: np.asarray(v) for k, v in (extra_columns or {}).items()}
    for name, col in extra.items():
        if name in layout.property_names:
            raise DivasInputError(src, f"the PLY already has a {name!r} property")
        if col.shape != (n_file,):
            raise ValueError(f"extra column {name!r} has shape {col.shape}, expected ({n_file},)")
    other = [e for e in layout.elements if e.name != "vertex"]
    other_data = {}
    if other:
        full = plyfile.PlyData.read(str(src))
        other_data = {e.name: full[e.name].data for e in other}
    vdt = layout.vertex_dtype()
    extra_dt = {k: v.dtype.newbyteorder("<") for k, v in extra.items()}
    le = np.dtype([(n, vdt[n].newbyteorder("<")) for n in vdt.names] + list(extra_dt.items()))
    with atomic_file(out) as f:  # temp + fsync + replace: a failure keeps the old file
        f.write(_header(layout, {"vertex": len(rows)}, extra_dt))
        for e in layout.elements:
            if e.name != "vertex":
                d = other_data[e.name]
                np.asarray(
                    d, dtype=[(n, d.dtype[n].newbyteorder("<")) for n in d.dtype.names]
                ).tofile(f)
                continue
            for start, chunk in iter_vertex_chunks(layout):
                lo, hi = np.searchsorted(rows, [start, start + len(chunk)])
                if hi > lo:
                    sel = rows[lo:hi]
                    part = np.empty(hi - lo, le)
                    for n in vdt.names:
                        part[n] = chunk[n][sel - start]
                    for n, col in extra.items():
                        part[n] = col[sel]
                    part.tofile(f)
    return len(rows)
