"""Reading a user's JSON file with one clear error naming the file."""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path
from typing import Any

from ..errors import DivasInputError

__all__ = ["read_json"]


def read_json(path: str | PathLike, what: str) -> Any:
    """Parse the JSON file ``path``; ``what`` names it in errors ("camera file", …).

    Raises:
        DivasInputError: missing, unreadable, or not valid JSON.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DivasInputError(path, f"{what} not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DivasInputError(path, f"cannot read {what} ({e})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise DivasInputError(path, f"not valid JSON ({e})") from None
