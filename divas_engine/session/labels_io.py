"""Multi-object label outputs (issue 6 item 3).

* :func:`write_labelled_ply` — the scene with one extra ``int divas_label`` vertex
  property (0 = unlabelled, k = object k). A standard PLY input is copied row for
  row in chunks (:func:`~divas_engine.io.ply.iter_vertex_chunks`): every original
  property keeps its bytes, the label column is appended; non-vertex elements are
  copied unchanged. Any other input (``.splat``, ``.spz``, compressed PLY, a
  generated scene) is written as a standard Gaussian PLY of the *decoded* scene
  (2DGS layout for 2DGS scenes; 3DGS layout with a flat third axis for 3DGS
  scenes, which were flattened to surfels on load) plus the label.
* :func:`file_label_values` — per input-file row labels (rows dropped on load → 0).
"""

from __future__ import annotations

import os
from os import PathLike
from pathlib import Path

import numpy as np
import plyfile

from ..errors import DivasInputError
from ..geometry import normalize_quats
from ..io.ply import iter_vertex_chunks, read_ply_header, write_ply_rows
from ..scene import SurfelScene, sh_coeff_count

__all__ = ["LABEL_PROPERTY", "file_label_values", "write_labelled_ply", "decoded_rows"]

#: Name of the appended vertex property.
LABEL_PROPERTY = "divas_label"

_PLY_TYPE = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
             "u4": "uint", "f4": "float", "f8": "double"}
#: Third (normal-axis) log-scale of 3DGS rows written for flattened surfels, relative to
#: the smaller tangent scale.
_FLAT_AXIS = 1e-3


def file_label_values(scene: SurfelScene, labels: np.ndarray) -> np.ndarray:
    """``[num_rows] int32`` label per input-file row from per-surfel ``labels``."""
    lab = np.asarray(labels)
    if lab.shape != (len(scene),):
        raise ValueError(f"labels must have shape ({len(scene)},), got {lab.shape}")
    if scene.source is None:
        return lab.astype(np.int32)
    out = np.zeros(scene.source.num_rows, np.int32)
    out[scene.source.kept_rows] = lab
    return out


def _ply_type(dt: np.dtype) -> str:
    return _PLY_TYPE[dt.kind + str(dt.itemsize)]


def _labelled_from_ply(src: Path, labels: np.ndarray, out: Path) -> None:
    layout = read_ply_header(src)
    if LABEL_PROPERTY in layout.property_names:
        raise DivasInputError(src, f"the PLY already has a '{LABEL_PROPERTY}' property")
    if len(labels) != layout.vertex.count:
        raise ValueError(f"{len(labels)} labels for {layout.vertex.count} vertex rows")
    vdt = layout.vertex_dtype()
    le_fields = [(n, vdt[n].newbyteorder("<")) for n in vdt.names]
    out_dt = np.dtype(le_fields + [(LABEL_PROPERTY, "<i4")])
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in layout.ply.comments]
    lines += [f"obj_info {c}" for c in layout.ply.obj_info]
    other = {}
    for e in layout.elements:
        if any(isinstance(p, plyfile.PlyListProperty) for p in e.properties):
            raise DivasInputError(src, f"list property in element {e.name!r} is not supported")
        lines.append(f"element {e.name} {e.count}")
        for p in e.properties:
            lines.append(f"property {_ply_type(np.dtype(p.val_dtype))} {p.name}")
        if e.name == "vertex":
            lines.append(f"property int {LABEL_PROPERTY}")
    if any(e.name != "vertex" for e in layout.elements):
        full = plyfile.PlyData.read(str(src))
        other = {e.name: full[e.name].data for e in layout.elements if e.name != "vertex"}
    header = ("\n".join(lines) + "\nend_header\n").encode("ascii")
    with open(out, "wb") as f:
        f.write(header)
        for e in layout.elements:
            if e.name != "vertex":
                d = other[e.name]
                np.asarray(d, dtype=[(n, d.dtype[n].newbyteorder("<")) for n in d.dtype.names]
                           ).tofile(f)
                continue
            for start, chunk in iter_vertex_chunks(layout):
                rows = np.empty(len(chunk), out_dt)
                for n in vdt.names:
                    rows[n] = chunk[n]
                rows[LABEL_PROPERTY] = labels[start:start + len(chunk)]
                rows.tofile(f)


def decoded_rows(scene: SurfelScene) -> np.ndarray:
    """Structured Gaussian-PLY rows (stored-space values) of a decoded scene.

    2DGS scenes: the 2DGS trainer layout; 3DGS scenes: the 3DGS layout with the
    dropped normal axis written as a flat ``scale_2``.
    """
    n = len(scene)
    k = sh_coeff_count(scene.sh_degree)
    three = scene.kind == "3dgs"
    fields = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    fields += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    fields += ["opacity", "scale_0", "scale_1"] + (["scale_2"] if three else [])
    fields += ["rot_0", "rot_1", "rot_2", "rot_3"]
    rows = np.zeros(n, dtype=[(f, "<f4") for f in fields])
    for i, a in enumerate("xyz"):
        rows[a] = scene.means[:, i]
    for ch in range(3):
        rows[f"f_dc_{ch}"] = scene.sh[:, 0, ch]
        for j in range(k - 1):
            rows[f"f_rest_{ch * (k - 1) + j}"] = scene.sh[:, j + 1, ch]
    o = np.clip(scene.opacities.astype(np.float64), 1e-7, 1 - 1e-7)
    rows["opacity"] = np.log(o / (1 - o))
    s = np.maximum(scene.scales.astype(np.float64), 1e-30)
    rows["scale_0"], rows["scale_1"] = np.log(s[:, 0]), np.log(s[:, 1])
    if three:
        rows["scale_2"] = np.log(_FLAT_AXIS * s.min(1))
    q = normalize_quats(scene.quats)
    for i in range(4):
        rows[f"rot_{i}"] = q[:, i]
    return rows


def write_labelled_ply(scene: SurfelScene, labels: np.ndarray, out: str | PathLike) -> Path:
    """Write ``scene`` with the per-surfel int ``labels`` as an extra ``divas_label`` column.

    The file is written to a temporary name and renamed (atomic).
    """
    out = Path(out)
    lab = np.asarray(labels)
    if lab.shape != (len(scene),) or not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels must be an int array of shape ({len(scene)},)")
    tmp = out.with_name(out.name + ".tmp")
    try:
        src = scene.source
        if src is not None and src.format == "ply":
            _labelled_from_ply(Path(src.path), file_label_values(scene, lab), tmp)
        else:
            base = decoded_rows(scene)
            rows = np.empty(len(base), np.dtype(base.dtype.descr + [(LABEL_PROPERTY, "<i4")]))
            for n in base.dtype.names:
                rows[n] = base[n]
            rows[LABEL_PROPERTY] = lab
            write_ply_rows(tmp, {"vertex": rows}, comments=["divas labelled scene"])
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return out
