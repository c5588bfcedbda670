"""``divas batch`` manifests: JSON or CSV rows, each one job.

JSON (``.json``)::

    {"version": 1,
     "defaults": {"segmenter": "graph3d", "scale": 0.5},
     "jobs": [{"name": "chair01", "scene": "caps/chair01/scene.ply",
               "cameras": "caps/chair01/cameras.json", "prompts": "prompts/chair.json",
               "output": "out/chair01", "options": {"seed": 1}}]}

(a bare list of rows is the same without ``defaults``). CSV (any other name): a header naming
``scene``, ``prompts``, ``output`` (required), ``cameras``, ``name``, ``options`` (a JSON
object) and any option by name; empty cells are unset, option cells are JSON when they parse.
Options are :class:`~divas_engine.segment_request.SegmentRequest` fields; a row's options
override ``defaults``; the outputs are set inside ``output``. Paths are relative to the
manifest's folder (or ``file://`` URIs) and read where the job runs. Names default to the
output folder's name; names and output folders are unique.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from ..errors import DivasInputError
from ..io.json_file import read_json, read_text
from ..io.limits import require_input_file
from ..segment_request import SegmentRequest, request_path
from .batch_jobs import BatchJob

__all__ = ["read_manifest", "parse_rows", "MANIFEST_VERSION"]

MANIFEST_VERSION = 1
_ROW_KEYS = {"name", "scene", "cameras", "prompts", "output", "options"}
#: set by the batch for every job (inside its output folder)
_NOT_OPTIONS = {"out", "labels_out", "report", "session", "resume", "scene", "prompts"}
_PATH_COLUMNS = {"name", "scene", "cameras", "prompts", "output"}


def _options(v: Any, where: str) -> dict[str, Any]:
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise DivasInputError(None, f"{where}: must be an object of options")
    out = {}
    for k, x in v.items():
        name = str(k).replace("-", "_")
        if name in _NOT_OPTIONS:
            raise DivasInputError(
                None,
                f"{where}.{k}: not an option (the batch names each job's outputs "
                "inside its 'output' folder; scene and prompts are row fields)",
            )
        out[name] = x
    return out


def parse_rows(rows: list[Any], base: Path, defaults: Any = None, source=None) -> list[BatchJob]:
    """Jobs of decoded manifest rows (module docstring), checked; ``source`` names the
    manifest in errors."""
    src = None if source is None else str(source)
    try:
        common = _options(defaults, "defaults")
        jobs: list[BatchJob] = []
        for i, row in enumerate(rows):
            where = f"jobs[{i}]"
            if not isinstance(row, dict):
                raise DivasInputError(None, f"{where}: must be an object")
            unknown = set(row) - _ROW_KEYS
            if unknown:
                raise DivasInputError(
                    None,
                    f"{where}: unknown keys {sorted(unknown)} (allowed: {sorted(_ROW_KEYS)}; "
                    "settings go under 'options')",
                )
            for need in ("scene", "prompts", "output"):
                if not (isinstance(row.get(need), str) and row[need]):
                    raise DivasInputError(None, f"{where}.{need}: missing (a path)")
            values = {**common, **_options(row.get("options"), f"{where}.options")}
            values.update({k: row[k] for k in ("scene", "prompts", "cameras") if k in row})
            req = SegmentRequest.from_mapping(values, base=base, where=where)
            output = request_path(row["output"], base, f"{where}.output")
            name = row.get("name", output.name)
            if not isinstance(name, str) or not name:
                raise DivasInputError(None, f"{where}.name: must be a non-empty string")
            jobs.append(BatchJob(i, name, req, output))
    except DivasInputError as e:
        raise DivasInputError(src, e.problem) from None
    for what, key in (("name", lambda j: j.name), ("output", lambda j: j.output.resolve())):
        seen: dict[Any, int] = {}
        for j in jobs:
            k = key(j)
            if k in seen:
                raise DivasInputError(
                    src, f"jobs[{seen[k]}] and jobs[{j.index}] have the same {what} ({k})"
                )
            seen[k] = j.index
    if not jobs:
        raise DivasInputError(src, "the manifest holds no jobs")
    return jobs


def _cell(column: str, text: str) -> Any:
    if column in _PATH_COLUMNS:
        return text
    try:
        return json.loads(text)
    except ValueError:
        return text


def _csv_rows(path: Path) -> list[dict[str, Any]]:
    text = read_text(path, "manifest").removeprefix("\ufeff")  # a spreadsheet's BOM
    try:
        table = list(csv.reader(io.StringIO(text)))
    except csv.Error as e:
        raise DivasInputError(path, f"not readable CSV ({e})") from None
    table = [r for r in table if any(c.strip() for c in r)]
    if not table:
        raise DivasInputError(path, "empty manifest")
    head = [h.strip() for h in table[0]]
    if len(set(head)) != len(head) or "" in head:
        raise DivasInputError(path, f"header row: columns must be named and unique ({head})")
    rows = []
    for n, r in enumerate(table[1:], start=2):
        if len(r) != len(head):
            raise DivasInputError(path, f"line {n}: {len(r)} cells, the header has {len(head)}")
        row: dict[str, Any] = {}
        options: dict[str, Any] = {}
        for col, cell in zip(head, r):
            cell = cell.strip()
            if not cell:
                continue
            if col == "options":
                try:
                    options.update(json.loads(cell))
                except (ValueError, TypeError):
                    raise DivasInputError(
                        path, f"line {n}: 'options' must hold a JSON object"
                    ) from None
            elif col in _ROW_KEYS:
                row[col] = cell
            else:
                options[col] = _cell(col, cell)
        if options:
            row["options"] = options
        rows.append(row)
    return rows


def read_manifest(path: str | Path) -> list[BatchJob]:
    """The jobs of the manifest at ``path`` (``.json``: JSON; else CSV)."""
    path = Path(path)
    require_input_file(path, "manifest")
    base = path.resolve().parent
    if path.suffix.lower() == ".json":
        doc = read_json(path, "manifest")
        defaults = None
        if isinstance(doc, dict):
            unknown = set(doc) - {"version", "defaults", "jobs"}
            if unknown:
                raise DivasInputError(
                    path, f"unknown keys {sorted(unknown)} (allowed: version, defaults, jobs)"
                )
            if doc.get("version") != MANIFEST_VERSION:
                raise DivasInputError(
                    path, f"version must be {MANIFEST_VERSION}, got {doc.get('version')!r}"
                )
            defaults, doc = doc.get("defaults"), doc.get("jobs")
        if not isinstance(doc, list):
            raise DivasInputError(
                path, "must hold a list of jobs (or {'version': 1, 'jobs': [...]})"
            )
        return parse_rows(doc, base, defaults, path)
    return parse_rows(_csv_rows(path), base, None, path)
