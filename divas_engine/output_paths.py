"""Checked, atomic outputs: every file DivAS writes goes through this module.

* :func:`check_output_path` / :func:`check_outputs` — the pre-flight, run *before* any
  loading or computation: the parent folder exists and is writable, the path is not a
  folder nor a FIFO / device, and it is not the same file as any input (resolved path
  or inode). Problems are a :class:`DivasInputError` naming the path.
* :func:`atomic_file` / :func:`atomic_path` — the write: a temporary file in the same
  folder, flushed and fsynced, then ``os.replace``\\ d over the target. Any failure
  (a full disk, a read-only folder, an interrupted writer) removes the temporary and
  leaves the previous file untouched, reported as one :class:`DivasInputError`. The
  file gets the user's normal permissions (``0666`` less the umask), not ``mkstemp``'s
  ``0600``.
* :func:`remove_stale_temps` — temporaries left by a killed writer (their process is
  gone) are removed by the next successful write of the same file, and by session
  saves and loads.

Temporary names are ``.<name>.<pid>-<token>.divas-tmp``; the pid lets a later process
tell a dead writer's leftover from a live one's file in progress.
"""

from __future__ import annotations

import errno
import json
import os
import secrets
import stat
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from os import PathLike
from pathlib import Path
from typing import IO, Any

import numpy as np

from .errors import DivasInputError

__all__ = [
    "TEMP_SUFFIX",
    "check_output_path",
    "check_outputs",
    "atomic_file",
    "atomic_path",
    "write_bytes_atomic",
    "write_text_atomic",
    "write_json_atomic",
    "save_npy_atomic",
    "save_npz_atomic",
    "write_image_atomic",
    "remove_stale_temps",
    "same_file",
    "file_mode",
    "dir_mode",
]

TEMP_SUFFIX = ".divas-tmp"

#: temporaries this process is writing now (never removed as stale).
_LIVE: set[str] = set()
_LIVE_LOCK = threading.Lock()


def _umask() -> int:
    try:  # Linux: read it without changing it (os.umask is process-global)
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _LIVE_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of a new file as ``open()`` would create it: ``0666`` less the umask."""
    return 0o666 & ~_umask()


def dir_mode() -> int:
    """Mode of a new folder as ``mkdir`` would create it: ``0777`` less the umask."""
    return 0o777 & ~_umask()


def same_file(a: str | PathLike, b: str | PathLike) -> bool:
    """True when ``a`` and ``b`` name the same file (resolved path, or same inode)."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.resolve() == pb.resolve():
            return True
        return os.path.samefile(pa, pb)
    except OSError:  # one does not exist (yet): not the same file
        return False


def _problem_of(err: OSError) -> str:
    name = errno.errorcode.get(err.errno or 0, "")
    text = err.strerror or str(err)
    return f"cannot write the output: {text}" + (f" ({name})" if name else "")


def check_output_path(
    path: str | PathLike,
    *,
    inputs: Iterable[str | PathLike | None] = (),
    what: str = "output",
    folder: bool = False,
) -> Path:
    """Pre-flight of one output path (``folder``: the output is a folder, which may
    exist or be created). Returns the path; raises :class:`DivasInputError` naming it."""
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise DivasInputError(p, f"the {what} path names no file")
    for src in inputs:
        if src is not None and same_file(p, src):
            raise DivasInputError(
                p, f"the {what} is the input file {src}; refusing to overwrite the input"
            )
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except OSError as e:
        raise DivasInputError(p, f"cannot use as {what}: {e.strerror}") from None
    if st is not None:
        if folder:
            if not stat.S_ISDIR(st.st_mode):
                raise DivasInputError(p, f"the {what} must be a folder, and this is a file")
            if not os.access(p, os.W_OK | os.X_OK):
                raise DivasInputError(p, f"the {what} folder is not writable")
            return p
        if stat.S_ISDIR(st.st_mode):
            raise DivasInputError(p, f"the {what} is a folder; give a file path")
        if not stat.S_ISREG(st.st_mode):
            raise DivasInputError(p, f"the {what} is not a regular file (a FIFO or device?)")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        if parent.exists():
            raise DivasInputError(p, f"the {what}'s parent {parent} is not a folder")
        if folder:
            # a folder output may create its missing parents, if an existing ancestor
            # is writable
            anc = parent
            while not anc.exists() and anc != anc.parent:
                anc = anc.parent
            if anc.is_dir() and os.access(anc, os.W_OK | os.X_OK):
                return p
        raise DivasInputError(p, f"the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise DivasInputError(p, f"the folder {parent} is not writable")
    return p


def check_outputs(
    outputs: Iterable[tuple[str, str | PathLike | None]],
    inputs: Iterable[str | PathLike | None] = (),
    *,
    folders: Iterable[str] = (),
) -> None:
    """Pre-flight of every ``(what, path)`` output (None = not requested) against the
    ``inputs`` and against each other; ``folders``: the ``what``\\ s that are folders."""
    ins = [i for i in inputs if i is not None]
    fold = set(folders)
    seen: list[tuple[str, Path]] = []
    for what, path in outputs:
        if path is None:
            continue
        p = check_output_path(path, inputs=ins, what=what, folder=what in fold)
        for w2, p2 in seen:
            if p.resolve() == p2.resolve():
                raise DivasInputError(p, f"the {what} and the {w2} are the same path")
        seen.append((what, p))


def _temp_for(path: Path) -> tuple[int, Path]:
    parent = path.parent if str(path.parent) else Path(".")
    for _ in range(100):
        tmp = parent / f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}{TEMP_SUFFIX}"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        return fd, tmp
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(path))


def _unlink_quietly(p: Path) -> None:
    with suppress(OSError):
        os.unlink(p)


@contextmanager
def _temporary(target: Path) -> Iterator[tuple[int, Path]]:
    """An open temporary ``(fd, path)`` beside ``target``, registered as being written;
    removed when the block leaves it behind (an error), OSErrors turned into one
    :class:`DivasInputError` naming ``target``; a killed earlier writer's leftovers of
    this file are removed afterwards."""
    if target.is_dir():
        raise DivasInputError(target, "the output is a folder; give a file path")
    try:
        fd, tmp = _temp_for(target)
    except OSError as e:
        raise DivasInputError(target, _problem_of(e)) from None
    with _LIVE_LOCK:
        _LIVE.add(str(tmp))
    try:
        try:
            yield fd, tmp
        except OSError as e:
            raise DivasInputError(target, _problem_of(e)) from None
    finally:
        if os.path.lexists(tmp):
            _unlink_quietly(tmp)
        with _LIVE_LOCK:
            _LIVE.discard(str(tmp))
    remove_stale_temps(target)


def _publish(tmp: Path, target: Path) -> None:
    """Normal permissions, then ``os.replace`` over ``target`` (the data is fsynced)."""
    os.chmod(tmp, file_mode())
    os.replace(tmp, target)


@contextmanager
def atomic_path(path: str | PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for a writer that needs a path; when the
    block ends without error the file is fsynced and replaces ``path``."""
    target = Path(path)
    with _temporary(target) as (fd, tmp):
        os.close(fd)
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        _publish(tmp, target)


@contextmanager
def atomic_file(path: str | PathLike, mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temporary beside ``path`` for writing (``"wb"`` or ``"w"``); when the block
    ends without error: flush, fsync, give normal permissions, ``os.replace`` over
    ``path``. On any error the temporary is removed and ``path`` is left as it was."""
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_file mode must be 'wb' or 'w', got {mode!r}")
    target = Path(path)
    with _temporary(target) as (fd, tmp):
        try:
            f = os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"}))
        except BaseException:
            os.close(fd)
            raise
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        _publish(tmp, target)


def write_bytes_atomic(path: str | PathLike, data: bytes) -> Path:
    with atomic_file(path) as f:
        f.write(data)
    return Path(path)


def write_text_atomic(path: str | PathLike, text: str) -> Path:
    return write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | PathLike, doc: Any, **dumps: Any) -> Path:
    return write_text_atomic(path, json.dumps(doc, **{"indent": 1, **dumps}))


def save_npy_atomic(path: str | PathLike, array: np.ndarray) -> Path:
    """``np.save`` to exactly ``path`` (no ``.npy`` appended), atomically."""
    with atomic_file(path) as f:
        np.save(f, np.asarray(array), allow_pickle=False)
    return Path(path)


def save_npz_atomic(path: str | PathLike, *, compressed: bool = True, **arrays: Any) -> Path:
    """``np.savez[_compressed]`` to exactly ``path``, atomically."""
    with atomic_file(path) as f:
        (np.savez_compressed if compressed else np.savez)(f, **arrays)
    return Path(path)


def write_image_atomic(path: str | PathLike, image_bgr: np.ndarray) -> Path:
    """An image (format by ``path``'s extension, OpenCV channel order), atomically."""
    import cv2

    p = Path(path)
    ok, buf = cv2.imencode(p.suffix or ".png", np.asarray(image_bgr))
    if not ok:
        raise DivasInputError(p, f"cannot encode an image as {p.suffix or '.png'}")
    return write_bytes_atomic(p, buf.tobytes())


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temps(path: str | PathLike) -> int:
    """Remove the temporaries of ``path`` left by writers that are gone (killed, or
    this process's own that are no longer being written). Returns how many."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    prefix = f".{p.name}."
    n = 0
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return 0
    for e in entries:
        name = e.name
        if not (name.startswith(prefix) and name.endswith(TEMP_SUFFIX)):
            continue
        tag = name[len(prefix) : -len(TEMP_SUFFIX)]
        pid_s, _, token = tag.partition("-")
        if not (pid_s.isdigit() and token):
            continue
        with _LIVE_LOCK:
            live = e.path in _LIVE or str(parent / name) in _LIVE
        if live or (int(pid_s) != os.getpid() and _pid_alive(int(pid_s))):
            continue
        _unlink_quietly(Path(e.path))
        n += 1
    return n
