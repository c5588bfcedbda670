"""Turn a failed engine call into one readable ``self.report`` line (no traceback)."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

from divas_engine.errors import DivasInputError

__all__ = ["USER_ERRORS", "report_failure"]

#: errors caused by the user's files or choices; anything else is a bug and propagates.
USER_ERRORS = (DivasInputError, OSError, ValueError, KeyError)


def report_failure(operator, exc: BaseException, path: str | PathLike | None = None) -> set[str]:
    """Report ``exc`` as an error on ``operator`` (naming ``path`` if the message does not)."""
    msg = str(exc) if not isinstance(exc, KeyError) else str(exc.args[0])
    if path is not None and Path(path).name not in msg:
        msg = f"{path}: {msg}"
    operator.report({"ERROR"}, msg)
    return {"CANCELLED"}
