"""Saved sessions: a JSON manifest plus one content-addressed ``.npz`` of arrays (never
pickle), saved as one atomic unit.

``save_state(path, doc, arrays)`` writes the arrays to ``<path>.<sha256[:16]>.npz`` (a
name that depends on the bytes, so it never overwrites the file the current manifest
names), then replaces the manifest ``<path>`` (JSON) last; both go through
:mod:`~divas_engine.output_paths` (temporary, fsync, ``os.replace``). A kill at any
moment leaves either the old manifest with its old arrays, or the new manifest with
its new arrays — never a torn pair. Array files no manifest names any more and the
temporaries of killed writers are removed on the next save (temporaries also on load).

Sessions in the older layout (arrays in ``<path>.npz``) load unchanged: the manifest
names its arrays file, and its SHA-256 guards it.
"""

from __future__ import annotations

import hashlib
import io
import json
import re
import threading
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DivasInputError, InputErrorCode
from ..io.json_file import read_json
from ..output_paths import TEMP_SUFFIX, remove_stale_temps, write_bytes_atomic

__all__ = [
    "SESSION_FORMAT",
    "SESSION_VERSION",
    "arrays_path",
    "save_state",
    "load_state",
    "atomic_write_bytes",
    "clean_session_files",
]

SESSION_FORMAT = "divas-session"
SESSION_VERSION = 1

#: one save at a time per process: the clean-up after a save must not remove the
#: arrays of another thread's save whose manifest has not landed yet.
_SAVE_LOCK = threading.Lock()


def arrays_path(path: str | PathLike, sha256: str | None = None) -> Path:
    """The arrays file of the session manifest ``path``: content-addressed by the first
    16 hex digits of its SHA-256; without a hash, the legacy ``<path>.npz``."""
    p = Path(path)
    return p.with_name(p.name + (f".{sha256[:16]}.npz" if sha256 else ".npz"))


def atomic_write_bytes(path: str | PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:mod:`~divas_engine.output_paths`)."""
    write_bytes_atomic(path, data)


def _arrays_pattern(path: Path) -> re.Pattern[str]:
    return re.compile(re.escape(path.name) + r"(\.[0-9a-f]{16})?\.npz")


def _legacy_temps(path: Path) -> list[Path]:
    """Temporaries of the pre-issue-14 writer (``mkstemp``: ``.<name>.<8 chars>.tmp``)."""
    out = []
    for name in (path.name, path.name + ".npz"):
        rx = re.compile(re.escape(f".{name}.") + r"[A-Za-z0-9_]{8}\.tmp")
        out += [p for p in path.parent.glob(f".{name}.*.tmp") if rx.fullmatch(p.name)]
    return out


def clean_session_files(path: str | PathLike, keep: str | None) -> int:
    """Remove the session ``path``'s stale temporaries, and (``keep`` given: the arrays
    file the manifest names) every other arrays file of it. Returns how many."""
    p = Path(path)
    n = remove_stale_temps(p)
    # temporaries of arrays files that never landed (a writer killed mid-write)
    tmp_rx = re.compile(
        r"\." + re.escape(p.name) + r"(\.[0-9a-f]{16}\.npz)\.\d+-[0-9a-f]+" + re.escape(TEMP_SUFFIX)
    )
    for t in p.parent.glob(f".{p.name}.*{TEMP_SUFFIX}"):
        m = tmp_rx.fullmatch(t.name)
        if m:
            n += remove_stale_temps(p.with_name(p.name + m.group(1)))
    for t in _legacy_temps(p):
        t.unlink(missing_ok=True)
        n += 1
    if keep is None:
        return n
    rx = _arrays_pattern(p)
    for cand in p.parent.glob(p.name + "*.npz"):
        if rx.fullmatch(cand.name) and cand.name != keep:
            n += remove_stale_temps(cand)
            cand.unlink(missing_ok=True)
            n += 1
    return n


def _names(manifest: Path, name: str) -> bool:
    """Whether the manifest on disk names the arrays file ``name``."""
    try:
        return json.loads(manifest.read_bytes()).get("arrays", {}).get("file") == name
    except (OSError, ValueError, AttributeError):
        return False


def save_state(path: str | PathLike, doc: dict[str, Any], arrays: dict[str, np.ndarray]) -> Path:
    """Write the session document and its arrays as one atomic unit; returns the manifest
    path. Raises :class:`DivasInputError` when it cannot be written (the previous save
    stays loadable)."""
    path = Path(path)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    blob = buf.getvalue()
    sha = hashlib.sha256(blob).hexdigest()
    ap = arrays_path(path, sha)
    doc = dict(doc)
    doc["arrays"] = {"file": ap.name, "sha256": sha, "keys": sorted(arrays)}
    manifest = json.dumps(doc, indent=1).encode()
    with _SAVE_LOCK:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(ap)
        write_bytes_atomic(ap, blob)  # a new name: the current manifest's file is untouched
        try:
            write_bytes_atomic(path, manifest)  # the save lands here, in one rename
        except BaseException:
            if not _names(path, ap.name):  # not the previous save's arrays: drop them
                ap.unlink(missing_ok=True)
            raise
        clean_session_files(path, keep=ap.name)
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
    name = meta.get("file", arrays_path(path).name) if isinstance(meta, dict) else None
    if not isinstance(name, str) or Path(name).name != name or name in ("", ".", ".."):
        raise DivasInputError(path, f"the session names a bad arrays file {name!r}")
    ap = path.with_name(name)
    with _SAVE_LOCK:
        clean_session_files(path, keep=None)
    try:
        blob = ap.read_bytes()
    except OSError as e:
        raise DivasInputError(ap, f"cannot read the session arrays ({e.strerror})") from None
    if meta.get("sha256") and hashlib.sha256(blob).hexdigest() != meta["sha256"]:
        raise DivasInputError(
            ap,
            "session arrays do not match the session file (torn save?)",
            code=InputErrorCode.TORN_SAVE,
        )
    try:
        with np.load(io.BytesIO(blob), allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (ValueError, OSError, EOFError, KeyError) as e:
        raise DivasInputError(ap, f"unreadable session arrays ({e})") from None
    return doc, arrays
