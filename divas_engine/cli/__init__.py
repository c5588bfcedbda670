"""``divas`` command line: one module per sub-command.

Each sub-command module exposes ``add_parser(subparsers)`` (registering its
arguments and ``func``). :func:`main` never prints a traceback:

* bad input (:class:`DivasInputError`) → one line naming the file, exit 2;
* environment problems — ``OSError`` (permission denied, disk full, name too long, …)
  and ``MemoryError`` → one line, exit 1;
* anything else is a bug → one line asking to report it, the traceback saved to a file
  whose path the line gives, exit 70 (``EX_SOFTWARE``).

Options shared by several sub-commands (``--seed``, ``--scale``, ``--size``) are range
checked here, once, before any work.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import math
import os
import sys
import tempfile
import traceback
from pathlib import Path

from ..errors import DivasInputError

__all__ = ["main", "build_parser"]

#: Sub-command modules, in ``--help`` order.
_COMMANDS = (
    "info",
    "generate",
    "render",
    "anchors",
    "segment",
    "batch",
    "session",
    "demo",
    "eval",
    "sam-export",
)
#: Sub-commands whose module has another name (``eval`` would shadow the builtin).
_MODULES = {"eval": "evaluate", "sam-export": "sam_export"}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="divas",
        description="DivAS: interactive, training-free 3D "
        "segmentation of Gaussian-splat and NeRF-grid scenes.",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _COMMANDS:
        importlib.import_module(f".{_MODULES.get(name, name)}", __name__).add_parser(sub)
    return p


#: Largest ``--scale``: an image side grows by this factor at most.
MAX_SCALE = 16.0
#: ``--seed`` must fit NumPy's legacy seeding (32 bits) as well as ``default_rng``.
MAX_SEED = 2**32 - 1
#: Exit status of an internal error (BSD ``EX_SOFTWARE``).
EXIT_INTERNAL = 70


def _check_common(args: argparse.Namespace) -> str | None:
    """What is wrong with the shared numeric options (None: nothing)."""
    seed = getattr(args, "seed", None)
    if isinstance(seed, int) and not 0 <= seed <= MAX_SEED:
        return f"--seed must be in 0..{MAX_SEED}, got {seed}"
    scale = getattr(args, "scale", None)
    if isinstance(scale, float) and not (math.isfinite(scale) and 0 < scale <= MAX_SCALE):
        return f"--scale must be in (0, {MAX_SCALE:g}], got {scale}"
    size = getattr(args, "size", None)
    if isinstance(size, int) and not 0 < size <= 1 << 31:
        return f"--size must be in 1..{1 << 31}, got {size}"
    return None


def _save_traceback(command: str) -> Path | None:
    """Write the current exception's traceback to a file; its path (None if unwritable)."""
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    text = f"divas {command} ({' '.join(sys.argv)})\n{traceback.format_exc()}"
    for folder in (Path(tempfile.gettempdir()), Path.cwd()):
        try:
            fd, name = tempfile.mkstemp(prefix=f"divas-crash-{stamp}-", suffix=".txt", dir=folder)
            with os.fdopen(fd, "w") as f:
                f.write(text)
            return Path(name)
        except OSError:
            continue
    return None


def _os_error(e: OSError) -> str:
    what = e.strerror or str(e) or type(e).__name__
    if e.filename is not None:
        what += f": {e.filename}"
        if e.filename2 is not None:
            what += f" -> {e.filename2}"
    return what


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    cmd = args.command
    bad = _check_common(args)
    if bad:
        print(f"divas {cmd}: error: {bad}", file=sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except DivasInputError as e:
        print(f"divas {cmd}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"divas {cmd}: interrupted", file=sys.stderr)
        return 130
    except OSError as e:  # the environment: permissions, a full disk, a name too long, …
        print(f"divas {cmd}: error: {_os_error(e)}", file=sys.stderr)
        return 1
    except MemoryError:
        print(
            f"divas {cmd}: error: out of memory (try a smaller --scale, scene or image)",
            file=sys.stderr,
        )
        return 1
    except Exception as e:  # noqa: BLE001 - a bug: one line, the traceback in a file
        saved = _save_traceback(cmd)
        where = f"the traceback is in {saved}" if saved else "no traceback file could be written"
        msg = f"{type(e).__name__}: {e}"
        if len(msg) > 300:
            msg = msg[:300] + "…"
        print(
            f"divas {cmd}: internal error ({msg}); please report it — {where}",
            file=sys.stderr,
        )
        return EXIT_INTERNAL
