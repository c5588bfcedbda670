"""Write a row subset of one level of a streamed LOD scene back as a streamed LOD scene.

The output is a folder holding ``lod-meta.json`` and one SOG unit per source unit that
keeps a row (``0_<k>/``, in the source's unit order), one level (the selection lives on
the loaded level only; other levels are other Gaussians). Each unit is written by
:func:`~.sog_subset.sog_subset_files` (codebooks and texels kept: kept Gaussians decode
bit-identically, in the source's order). The tree keeps the source's nodes that still
hold a kept row; each leaf's reference is re-pointed into its new unit (its kept rows
are contiguous there: the source's offsets, less the dropped rows before them).
Bounds stay the source's (they bound the subset; tight ones would need every kept
Gaussian's extent), like SOG's ``means`` ranges. The environment is not written.
"""

from __future__ import annotations

import copy
import json
from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..scene import SourceInfo
from .gaussians import check_file_rows
from .lod import LOD_META, is_lod_meta, read_lod_meta
from .sog import read_sog_texels
from .sog_subset import sog_subset_files, write_folder_atomic

__all__ = ["write_lod_subset"]


def _target(out: Path) -> Path:
    """The output folder: ``out``'s when it names ``…lod-meta.json``, else ``out`` itself."""
    if is_lod_meta(out):
        if out.name != LOD_META:
            raise DivasInputError(out, f"a streamed LOD export is a folder's {LOD_META}")
        return out.parent
    if out.suffix and not out.is_dir():
        raise DivasInputError(
            out, f"a streamed LOD scene exports as a folder (or its {LOD_META}), not {out.suffix}"
        )
    return out


def _check_target(target: Path, source: Path) -> None:
    if target.resolve() == source.parent.resolve():
        raise DivasInputError(target, "refusing to overwrite the input scene with the export")
    if target.exists() and not target.is_dir():
        raise DivasInputError(target, "exists and is not a folder (streamed LOD export)")
    if target.is_dir():
        for p in target.iterdir():
            unit = p.is_dir() and all(
                f.is_file() and (f.name == "meta.json" or f.suffix.lower() == ".webp")
                for f in p.iterdir()
            )
            if not (unit or (p.is_file() and p.name == LOD_META)):
                raise DivasInputError(
                    target,
                    f"refusing to replace a folder that holds more than a LOD scene ({p.name})",
                )


def _tree(node: dict, level: int, new_ref) -> dict | None:
    """``node`` with only ``level``'s references, re-pointed; None when nothing is kept."""
    out = {k: copy.deepcopy(v) for k, v in node.items() if k not in ("children", "lods")}
    kids = [k for k in (_tree(c, level, new_ref) for c in node.get("children", [])) if k]
    ref = node.get("lods", {}).get(str(level))
    kept = new_ref(ref) if ref is not None else None
    if not kids and kept is None:
        return None
    if kids:
        out["children"] = kids
    if kept is not None:
        out["lods"] = {"0": kept}
    return out


def write_lod_subset(
    source: SourceInfo, level: int, file_rows: np.ndarray, out_path: str | PathLike
) -> Path:
    """Write rows ``file_rows`` (ascending) of level ``level`` of the LOD scene ``source``
    to the folder ``out_path`` (or the folder of ``…/lod-meta.json``); returns its
    ``lod-meta.json``.

    Raises:
        DivasInputError: the output is the input's folder, a file, or a folder holding
        more than a LOD scene; the source changed since it was loaded.
    """
    m = read_lod_meta(source.path)
    units = m.units[level]
    n = sum(c for _, c in units)
    if n != source.num_rows:
        raise DivasInputError(
            m.path, f"level {level} holds {n} Gaussians, {source.num_rows} when loaded"
        )
    rows = np.unique(check_file_rows(m.path, file_rows, n))
    if rows.size == 0:
        raise ValueError("nothing to write: file_rows is empty")
    target = _target(Path(out_path))
    _check_target(target, m.path)
    files: dict[str, bytes] = {}
    names: list[str] = []
    new_file: dict[int, int] = {}
    kept_before: dict[int, np.ndarray] = {}  # per unit: kept rows before each row (cumsum)
    start = 0
    for f, count in units:
        mine = rows[(rows >= start) & (rows < start + count)] - start
        start += count
        if mine.size == 0:
            continue
        cont, meta, layout, tex = read_sog_texels(m.unit_path(f))
        if layout.count != count:
            raise DivasInputError(cont.path, f"holds {layout.count} Gaussians, {count} when loaded")
        name = f"0_{len(names)}"
        for k, data in sog_subset_files(meta, layout, tex, mine, str(target / name)).items():
            files[f"{name}/{k}"] = data
        new_file[f] = len(names)
        names.append(f"{name}/meta.json")
        keep = np.zeros(count, bool)
        keep[mine] = True
        kept_before[f] = np.concatenate([[0], np.cumsum(keep)])

    def new_ref(ref: dict) -> dict | None:
        f, o, c = ref["file"], ref["offset"], ref["count"]
        if f not in kept_before:
            return None
        cum = kept_before[f]
        kept = int(cum[o + c] - cum[o])
        return {"file": new_file[f], "offset": int(cum[o]), "count": kept} if kept else None

    tree = _tree(m.doc["tree"], level, new_ref) or {"lods": {}}
    was = m.doc.get("asset", {}).get("generator") if isinstance(m.doc.get("asset"), dict) else None
    doc = {
        "version": 1,
        "asset": {"generator": "DivAS subset export" + (f" of {was}" if was else "")},
        "count": int(rows.size),
        "counts": [int(rows.size)],
        "lodLevels": 1,
        "filenames": names,
        "tree": tree,
    }
    files[LOD_META] = json.dumps(doc).encode()
    target.parent.mkdir(parents=True, exist_ok=True)
    write_folder_atomic(target, files)
    return target / LOD_META
