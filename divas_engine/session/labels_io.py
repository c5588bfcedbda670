"""Multi-object label outputs.

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

from os import PathLike
from pathlib import Path

import numpy as np

from ..io.ply import surfel_rows, write_ply_rows
from ..io.ply_subset import write_ply_subset
from ..kinds import SceneKind
from ..output_paths import check_output_path
from ..scene import SurfelScene

__all__ = ["LABEL_PROPERTY", "file_label_values", "write_labelled_ply", "decoded_rows"]

#: Name of the appended vertex property.
LABEL_PROPERTY = "divas_label"

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


def decoded_rows(scene: SurfelScene) -> np.ndarray:
    """Structured Gaussian-PLY rows (stored-space values) of a decoded scene.

    2DGS scenes: the 2DGS trainer layout; 3DGS scenes: the 3DGS layout with the
    dropped normal axis written as a flat ``scale_2``.
    """
    return surfel_rows(scene, flat_axis=_FLAT_AXIS if scene.kind == SceneKind.GS3D else None)


def write_labelled_ply(scene: SurfelScene, labels: np.ndarray, out: str | PathLike) -> Path:
    """Write ``scene`` with the per-surfel int ``labels`` as an extra ``divas_label`` column.

    The file is written through :mod:`~divas_engine.output_paths` (temporary, fsync,
    rename): a failure keeps any previous file; the output may not be the input.
    """
    out = Path(out)
    lab = np.asarray(labels)
    if lab.shape != (len(scene),) or not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels must be an int array of shape ({len(scene)},)")
    src = scene.source
    check_output_path(out, inputs=[] if src is None else [src.path], what="labelled PLY")
    if src is not None and src.format == "ply":
        write_ply_subset(
            src.path, None, out, extra_columns={LABEL_PROPERTY: file_label_values(scene, lab)}
        )
    else:
        base = decoded_rows(scene)
        rows = np.empty(len(base), np.dtype(base.dtype.descr + [(LABEL_PROPERTY, "<i4")]))
        for n in base.dtype.names:
            rows[n] = base[n]
        rows[LABEL_PROPERTY] = lab
        write_ply_rows(out, {"vertex": rows}, comments=["divas labelled scene"])
    return out
