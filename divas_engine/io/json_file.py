"""Reading a user's JSON file with one clear error naming the file."""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path
from typing import Any

from ..errors import DivasInputError
from .limits import limits, require_input_file

__all__ = ["read_json", "read_text"]


def read_text(path: str | PathLike, what: str) -> str:
    """The UTF-8 text of the user's file ``path`` (at most ``LoadLimits.max_json_bytes``);
    ``what`` names it in errors.

    Raises:
        DivasInputError: missing, unreadable, too large, or not UTF-8.
    """
    path = Path(path)
    try:
        missing = not path.exists() and not path.is_symlink()
    except OSError:  # e.g. a name too long: require_input_file reports it
        missing = False
    if missing:
        raise DivasInputError(path, f"{what} not found")
    require_input_file(path, what)
    cap = limits().max_json_bytes
    try:
        with open(path, "rb") as f:
            raw = f.read(cap + 1)
        if len(raw) > cap:
            raise DivasInputError(path, f"{what} is larger than {cap} bytes (LoadLimits)")
        return raw.decode("utf-8")
    except OSError as e:
        raise DivasInputError(path, f"cannot read {what} ({e.strerror or e})") from None
    except UnicodeDecodeError as e:
        raise DivasInputError(path, f"cannot read {what}: not UTF-8 text ({e})") from None


def read_json(path: str | PathLike, what: str) -> Any:
    """Parse the JSON file ``path``; ``what`` names it in errors ("camera file", …).

    Raises:
        DivasInputError: missing, unreadable, or not valid JSON.
    """
    text = read_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise DivasInputError(path, f"not valid JSON ({e})") from None
    except RecursionError:
        raise DivasInputError(path, f"{what} is nested too deeply to be read") from None
    except ValueError as e:  # e.g. an integer literal longer than Python converts
        raise DivasInputError(path, f"not readable JSON ({e})") from None
