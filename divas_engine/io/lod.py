"""PlayCanvas streamed LOD scenes (``lod-meta.json``), loaded one level at a time.

The format is what splat-transform writes (``write-lod.ts``) and reads (``read-lod.ts``).
``lod-meta.json`` holds ``version`` (1, or absent), ``lodLevels``, optional ``count(s)``,
``filenames`` (the SOG units, unbundled ``meta.json`` folders), an optional ``environment`` SOG
and a spatial ``tree`` whose leaves map ``"<level>"`` to ``{file, offset, count}`` rows of a
unit.

One level is the concatenation of its units in ascending file index, each unit's rows in order,
so its rows are what ``splat-transform lod-meta.json -L <level>`` writes; the environment is not
part of a level. Every unit is a SOG scene (:mod:`.sog`) whose count must equal the tree's
references to it; a unit holds one level only. ``scene.extras`` gets ``lod_level``,
``lod_levels``, ``lod_counts`` and ``lod_units`` (``[[file name, count], ...]``, row order).
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from ..errors import DivasInputError
from ..kinds import SceneKind
from ..scene import SurfelScene
from .gaussians import scene_from_rows
from .json_file import read_json
from .sog import INVALID_WHAT, sog_rows

__all__ = ["LodManifest", "LodRef", "LOD_META", "is_lod_meta", "read_lod_meta", "read_lod"]

LOD_META = "lod-meta.json"


def is_lod_meta(path: str | PathLike) -> bool:
    """True for a file named ``…lod-meta.json`` (how splat-transform tells the format)."""
    return Path(path).name.lower().endswith(LOD_META)


@dataclass(frozen=True)
class LodRef:
    """A tree leaf's Gaussians of one level: rows ``offset..offset+count`` of unit ``file``."""

    level: int
    file: int
    offset: int
    count: int


@dataclass(frozen=True)
class LodManifest:
    """A parsed ``lod-meta.json``.

    Attributes:
        path: the file; doc: its JSON; levels: ``lodLevels``; filenames: the units.
        counts: Gaussians per level (declared, else summed from the tree).
        refs: every leaf reference, in tree order (depth first).
        units: per level, ``[(file index, count)]`` in ascending file index.
    """

    path: Path
    doc: dict
    levels: int
    filenames: tuple[str, ...]
    counts: tuple[int, ...]
    refs: tuple[LodRef, ...]
    units: tuple[tuple[tuple[int, int], ...], ...]

    def unit_path(self, file: int) -> Path:
        return self.path.parent / self.filenames[file]

    def level(self, lod: int | None) -> int:
        """The level ``lod`` names (None: 0, the finest; negative: from the coarsest)."""
        n = self.levels
        k = 0 if lod is None else int(lod)
        if not -n <= k < n:
            raise DivasInputError(self.path, f"no level {lod}: the scene has levels 0..{n - 1}")
        return k % n


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _leaf_refs(tree: Any, levels: int, files: int, bad) -> list[LodRef]:
    refs: list[LodRef] = []
    stack = [tree]
    while stack:
        node = stack.pop()
        if not isinstance(node, dict):
            raise bad("tree: every node must be an object")
        children = node.get("children", [])
        lods = node.get("lods", {})
        if not isinstance(children, list) or not isinstance(lods, dict):
            raise bad("tree: 'children' must be a list and 'lods' an object")
        for key, ref in lods.items():
            lvl = int(key) if isinstance(key, str) and key.isascii() and key.isdigit() else -1
            ok = (
                0 <= lvl < levels
                and isinstance(ref, dict)
                and all(_int(ref.get(k)) and ref[k] >= 0 for k in ("file", "offset", "count"))
                and ref["file"] < files
            )
            if not ok:
                raise bad(f"tree: bad reference {key!r}: {ref!r}")
            refs.append(LodRef(lvl, ref["file"], ref["offset"], ref["count"]))
        stack.extend(reversed(children))
    return refs


def read_lod_meta(path: str | PathLike) -> LodManifest:
    """Parse and check ``lod-meta.json`` (as splat-transform's reader checks it, plus the
    unit names staying inside the scene's folder and one level per unit)."""
    path = Path(path)
    doc = read_json(path, "lod-meta.json")

    def bad(problem: str) -> DivasInputError:
        return DivasInputError(path, f"bad lod-meta.json: {problem}")

    if not isinstance(doc, dict):
        raise bad("must hold a JSON object")
    if doc.get("version", 1) != 1:
        raise DivasInputError(path, f"unsupported lod-meta.json version {doc.get('version')!r}")
    levels = doc.get("lodLevels")
    if not (_int(levels) and levels > 0):
        raise bad(f"'lodLevels' must be a positive integer, got {levels!r}")
    names = doc.get("filenames")
    if not (isinstance(names, list) and all(isinstance(n, str) and n for n in names)):
        raise bad("'filenames' must be a list of file names")
    for n in names:
        p = PurePosixPath(n)
        if p.is_absolute() or ".." in p.parts or "\\" in n:
            raise bad(f"file name {n!r} leaves the scene's folder")
    if not isinstance(doc.get("tree"), dict):
        raise bad("'tree' must be an object")
    refs = _leaf_refs(doc["tree"], levels, len(names), bad)
    per_unit: dict[int, dict[int, int]] = {}
    level_of: dict[int, int] = {}
    ends: dict[int, int] = {}
    for r in refs:
        if level_of.setdefault(r.file, r.level) != r.level:
            raise bad(f"unit {names[r.file]!r} holds levels {level_of[r.file]} and {r.level}")
        per_unit.setdefault(r.level, {})
        per_unit[r.level][r.file] = per_unit[r.level].get(r.file, 0) + r.count
        ends[r.file] = max(ends.get(r.file, 0), r.offset + r.count)
    units = tuple(tuple(sorted(per_unit.get(lvl, {}).items())) for lvl in range(levels))
    for f, end in ends.items():
        total = per_unit[level_of[f]][f]
        if end > total:
            raise bad(f"unit {names[f]!r}: a reference ends at row {end} of {total}")
    summed = tuple(sum(c for _, c in u) for u in units)
    counts = doc.get("counts")
    if counts is not None:
        if not (
            isinstance(counts, list)
            and len(counts) == levels
            and all(_int(c) and c >= 0 for c in counts)
        ):
            raise bad(f"'counts' must list {levels} non-negative integers")
        for lvl, (want, got) in enumerate(zip(counts, summed)):
            if want != got:
                raise bad(f"level {lvl}: 'counts' gives {want}, the tree {got}")
    return LodManifest(path, doc, levels, tuple(names), summed, tuple(refs), units)


def read_lod(path: str | PathLike, lod: int | None = None) -> SurfelScene:
    """Load level ``lod`` (None: 0, the finest) of a streamed LOD scene as one scene.

    Raises:
        DivasInputError: a bad ``lod-meta.json``, no such level, a unit that is missing,
        not a SOG, or whose count is not the tree's.
    """
    m = read_lod_meta(path)
    level = m.level(lod)
    units = m.units[level]
    if not units:
        raise DivasInputError(m.path, f"level {level} holds no Gaussians")
    parts = []
    for f, count in units:
        cont, meta, layout, arrays, valid = sog_rows(m.unit_path(f))
        if layout.count != count:
            raise DivasInputError(
                cont.path,
                f"holds {layout.count} Gaussians, lod-meta.json gives {count} for level {level}",
            )
        parts.append((layout, meta, arrays, valid))
    deg = max(p[0].sh_bands for p in parts)
    n_sh = (deg + 1) ** 2
    cols = []
    for k in range(6):
        items = [p[2][k] for p in parts]
        if k == 4:  # SH: pad units with fewer bands with zeros (no view dependence)
            items = [np.pad(a, ((0, 0), (0, n_sh - a.shape[1]), (0, 0))) for a in items]
        cols.append(np.concatenate(items))
    *arrays, scale_n = cols
    first = parts[0]
    extras = {
        "lod_level": level,
        "lod_levels": m.levels,
        "lod_counts": list(m.counts),
        "lod_units": [[m.filenames[f], c] for f, c in units],
        "sog_version": first[0].version or 1,
        "splat_model": str(first[1].get("model", "default")),
    }
    return scene_from_rows(
        m.path,
        "lod",
        tuple(arrays),
        np.concatenate([p[3] for p in parts]),
        deg,
        SceneKind.GS3D,
        extras,
        invalid_what=INVALID_WHAT,
        scale_n=scale_n,
    )
