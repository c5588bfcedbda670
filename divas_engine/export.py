"""Export a selection back to disk in the input's own format (paper Sec. 3.6 output).

* Surfel scenes: the selected primitives as a subset of the *original* file —
  standard PLY rows are copied byte-for-byte (every property, order, type);
  ``.splat``/``.spz``/compressed PLY are written in their own format; SOG as SOG
  (bundled ``.sog`` or a ``meta.json`` folder, the source's codebooks and texels
  kept, :mod:`.io.sog_subset`); a streamed LOD level as a one-level ``lod-meta.json``
  folder (:mod:`.io.lod_subset`).
* ``labels.npy``: bool per *input* primitive (file row order; rows dropped on
  load for NaN/Inf are False).
* Density grids: the masked grid in its source's format — ``.npz`` (density zeroed
  outside the selection, plus the boolean ``mask``), an instant-ngp snapshot or torch-ngp
  checkpoint whose density-grid cells are zero outside the object (the tool then renders
  the object alone), ``.vdb`` — and optionally the masked density as ``.vdb`` too.
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from .errors import DivasInputError
from .output_paths import check_outputs, save_npy_atomic
from .scene import DensityGrid, Scene, SurfelScene

__all__ = ["ExportResult", "file_labels", "export_selection"]


@dataclass(frozen=True)
class ExportResult:
    path: Path
    format: str
    count: int
    labels_path: Path | None = None


def _check_selection(scene: Scene, selection: np.ndarray) -> np.ndarray:
    sel = np.asarray(selection)
    expected = scene.density.shape if isinstance(scene, DensityGrid) else (len(scene),)
    if sel.dtype != bool or sel.shape != expected:
        raise ValueError(
            f"selection must be a bool array of shape {expected}, got {sel.dtype} {sel.shape}"
        )
    return sel


def _write_masked_grid(scene: DensityGrid, sel: np.ndarray, out_path: Path) -> str:
    """The masked grid in its source's format; returns the format written."""
    fmt = scene.source.format if scene.source is not None else "npz"
    if fmt in ("ingp", "msgpack"):
        from .io.instant_ngp import write_masked_instant_ngp

        write_masked_instant_ngp(scene, sel, out_path)
    elif fmt == "torch_ngp":
        from .io.torch_ngp import write_masked_torch_ngp

        write_masked_torch_ngp(scene, sel, out_path)
    elif fmt == "vdb":
        from .io.openvdb_grid import write_vdb

        write_vdb(out_path, scene, np.where(sel, scene.density, 0).astype(np.float32))
    else:
        from .io.density_grid import write_density_grid

        masked = DensityGrid(
            np.where(sel, scene.density, 0).astype(np.float32), scene.aabb, scene.rgb
        )
        write_density_grid(out_path, masked, mask=sel)
        fmt = "npz"
    return fmt


def file_labels(scene: SurfelScene, selection: np.ndarray) -> np.ndarray:
    """``[num_rows]`` bool per input-file primitive from a per-scene-primitive selection."""
    sel = _check_selection(scene, selection)
    if scene.source is None:
        return sel.copy()
    out = np.zeros(scene.source.num_rows, dtype=bool)
    out[scene.source.kept_rows[sel]] = True
    return out


def export_selection(
    scene: Scene,
    selection: np.ndarray,
    out_path: str | PathLike,
    *,
    labels_path: str | PathLike | None = None,
    vdb_path: str | PathLike | None = None,
) -> ExportResult:
    """Write the selected primitives (or voxels) of ``scene`` to ``out_path``; a density
    grid also as ``vdb_path`` (the masked density as OpenVDB) when given."""
    out_path = Path(out_path)
    sel = _check_selection(scene, selection)
    src = getattr(scene, "source", None)
    sog = src is not None and src.format in ("sog", "lod")  # they check their own folders
    check_outputs(
        [
            ("export", None if sog else out_path),
            ("labels output", labels_path),
            ("OpenVDB output", vdb_path),
        ],
        [] if src is None else [src.path],
    )
    if isinstance(scene, DensityGrid):
        fmt = _write_masked_grid(scene, sel, out_path)
        if vdb_path is not None:
            from .io.openvdb_grid import write_vdb

            write_vdb(vdb_path, scene, np.where(sel, scene.density, 0).astype(np.float32))
        if labels_path is not None:
            save_npy_atomic(labels_path, sel)
        return ExportResult(
            out_path, fmt, int(sel.sum()), None if labels_path is None else Path(labels_path)
        )
    if not sel.any():
        raise DivasInputError(out_path, "nothing to export: the selection is empty")
    if src is None:  # generated scene: write a 2DGS PLY of the selected surfels
        from .io.ply import write_surfel_ply

        write_surfel_ply(out_path, scene.subset(sel))
        fmt = "ply"
    else:
        rows = src.kept_rows[sel]
        fmt = src.format
        if fmt == "ply":
            from .io.ply_subset import write_ply_subset

            write_ply_subset(src.path, rows, out_path)
        elif fmt == "compressed_ply":
            from .io.compressed_ply import write_compressed_ply_subset

            write_compressed_ply_subset(src, rows, out_path)
        elif fmt == "splat":
            from .io.splat import write_splat_subset

            write_splat_subset(src, rows, out_path)
        elif fmt == "spz":
            from .io.spz import write_spz_subset

            write_spz_subset(src, rows, out_path)
        elif fmt == "sog":
            from .io.sog_subset import write_sog_subset

            out_path = write_sog_subset(src, rows, out_path)
        elif fmt == "lod":
            from .io.lod_subset import write_lod_subset

            out_path = write_lod_subset(src, int(scene.extras["lod_level"]), rows, out_path)
        else:
            raise DivasInputError(src.path, f"cannot export scenes read from format {fmt!r}")
    lp = None
    if labels_path is not None:
        lp = save_npy_atomic(labels_path, file_labels(scene, sel))
    return ExportResult(out_path, fmt, int(sel.sum()), lp)
