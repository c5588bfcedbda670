"""A session's files: one per object and the label set (the formats are
:mod:`divas_engine.export` and the backend's)."""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..output_paths import check_output_path
from ..scene import Scene
from .backends import SessionBackend
from .state import SessionState

__all__ = ["export_objects"]


def export_objects(
    scene: Scene,
    backend: SessionBackend,
    state: SessionState,
    label_set: np.ndarray,
    out_dir: str | PathLike,
) -> dict[str, Any]:
    """One file per object with a selection, in the input's own format, plus the label
    set (``label_set``); the files written."""
    from ..export import export_selection

    out = Path(out_dir)
    check_output_path(out, what="objects folder", folder=True)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Any] = {"objects": []}
    ext = backend.object_suffix()
    for o, sel in state.object_selections():
        if not sel.any():
            continue
        safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in o.name)
        p = out / f"{o.label:02d}_{safe}{ext}"
        export_selection(scene, sel, p)
        files["objects"].append(
            {"name": o.name, "label": o.label, "path": str(p), "count": int(sel.sum())}
        )
    files["labelled"] = str(backend.write_label_set(label_set, out))
    return files
