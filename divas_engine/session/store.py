"""Saved sessions: one JSON document plus one ``.npz`` of arrays (never pickle).

``save_state(path, doc, arrays)`` writes ``<path>`` (JSON) and ``<path>.npz``; each
is written to a temporary file and renamed into place (atomic on POSIX), the npz
first; the JSON records the npz's SHA-256 so a reader can tell a torn pair.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DivasInputError
from ..io.json_file import read_json

__all__ = [
    "SESSION_FORMAT",
    "SESSION_VERSION",
    "arrays_path",
    "save_state",
    "load_state",
    "atomic_write_bytes",
]

SESSION_FORMAT = "divas-session"
SESSION_VERSION = 1


def arrays_path(path: str | PathLike) -> Path:
    p = Path(path)
    return p.with_name(p.name + ".npz")


def atomic_write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_state(path: str | PathLike, doc: dict[str, Any], arrays: dict[str, np.ndarray]) -> Path:
    """Write the session document and its arrays atomically; returns the JSON path."""
    import io

    path = Path(path)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    blob = buf.getvalue()
    ap = arrays_path(path)
    atomic_write_bytes(ap, blob)
    doc = dict(doc)
    doc["arrays"] = {
        "file": ap.name,
        "sha256": hashlib.sha256(blob).hexdigest(),
        "keys": sorted(arrays),
    }
    atomic_write_bytes(path, json.dumps(doc, indent=1).encode())
    return path


def load_state(path: str | PathLike) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read a saved session: ``(document, arrays)``."""
    path = Path(path)
    doc = read_json(path, "session file")
    if not isinstance(doc, dict) or doc.get("format") != SESSION_FORMAT:
        raise DivasInputError(path, f"not a DivAS session file (format != {SESSION_FORMAT!r})")
    if doc.get("version") != SESSION_VERSION:
        raise DivasInputError(path, f"unsupported session version {doc.get('version')!r}")
    meta = doc.get("arrays") or {}
    ap = path.with_name(meta.get("file", arrays_path(path).name))
    try:
        blob = ap.read_bytes()
    except OSError as e:
        raise DivasInputError(ap, f"cannot read the session arrays ({e})") from None
    if meta.get("sha256") and hashlib.sha256(blob).hexdigest() != meta["sha256"]:
        raise DivasInputError(ap, "session arrays do not match the session file (torn save?)")
    import io

    with np.load(io.BytesIO(blob), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return doc, arrays
