"""Ground-truth labels from a ``.npy`` file, in the scene's order.

The oracle segmenter's target and the reference of the 3D scores: one bool per surfel
(given per surfel, or per input row of the scene's file — rows dropped on load are
dropped here too) or a ``[D,H,W]`` bool grid for a density grid. ``0``/``1`` integers
count as bool.
"""

from __future__ import annotations

from os import PathLike

import numpy as np

from ..errors import DivasInputError
from ..io.limits import require_input_file
from ..scene import Scene, SurfelScene

__all__ = ["load_ground_truth"]


def load_ground_truth(path: str | PathLike, scene: Scene) -> np.ndarray:
    """Ground truth in scene order: per surfel (given per input row or per surfel) / grid."""
    require_input_file(path, "ground-truth labels file")
    try:  # memory-mapped first: a header declaring more than the file holds fails here
        g = np.load(path, mmap_mode="r", allow_pickle=False)
        if not isinstance(g, np.ndarray):
            raise ValueError("not a single .npy array")
        if g.dtype.fields is not None or g.dtype.hasobject:
            raise ValueError(f"dtype {g.dtype} is not plain")
        g = np.array(g)
    except (OSError, ValueError, EOFError, TypeError, SyntaxError) as e:
        raise DivasInputError(path, f"cannot read ground-truth labels ({e})") from None
    if g.dtype != bool and not (np.issubdtype(g.dtype, np.integer) and np.isin(g, (0, 1)).all()):
        raise DivasInputError(path, f"ground-truth labels must be bool (or 0/1), got {g.dtype}")
    g = g.astype(bool)
    if isinstance(scene, SurfelScene):
        src = scene.source
        if g.shape == (len(scene),):
            return g
        if src is not None and g.shape == (src.num_rows,):
            return g[src.kept_rows]
        raise DivasInputError(
            path,
            f"ground-truth labels have shape {g.shape}; the scene has "
            f"{len(scene)} surfels" + (f" ({src.num_rows} input rows)" if src else ""),
        )
    if g.shape != scene.density.shape:
        raise DivasInputError(
            path, f"ground-truth grid has shape {g.shape}, the density grid {scene.density.shape}"
        )
    return g
