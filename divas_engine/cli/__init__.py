"""``divas`` command line: one module per sub-command.

Each sub-command module exposes ``add_parser(subparsers)`` (registering its
arguments and ``func``). :func:`main` turns :class:`DivasInputError` into a
one-line message and exit code 2 — never a traceback for bad input.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import DivasInputError

__all__ = ["main", "build_parser"]

#: Sub-command modules, in ``--help`` order.
_COMMANDS = ("info", "generate", "render", "anchors", "segment", "demo", "eval", "sam-export")
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


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except DivasInputError as e:
        print(f"divas {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"divas {args.command}: interrupted", file=sys.stderr)
        return 130
