"""Turn a failed engine call into one readable ``self.report`` line (no traceback)."""

from __future__ import annotations

import sys
import traceback
from os import PathLike
from pathlib import Path

from divas_engine.errors import DivasInputError

__all__ = ["USER_ERRORS", "SESSION_ERRORS", "report_failure", "report_exception"]

#: errors caused by the user's files or choices; anything else is a bug and propagates.
USER_ERRORS = (DivasInputError, OSError, ValueError, KeyError)
#: failures of a session step reported as one line (anything else is reported with its
#: type, the traceback going to the console).
SESSION_ERRORS = (*USER_ERRORS, ImportError, RuntimeError)


def report_failure(operator, exc: BaseException, path: str | PathLike | None = None) -> set[str]:
    """Report ``exc`` as an error on ``operator`` (naming ``path`` if the message does not)."""
    msg = str(exc) if not isinstance(exc, KeyError) else str(exc.args[0])
    if path is not None and Path(path).name not in msg:
        msg = f"{path}: {msg}"
    operator.report({"ERROR"}, msg)
    return {"CANCELLED"}


def report_exception(operator, exc: BaseException) -> set[str]:
    """One readable ``ERROR`` line on ``operator``; unexpected errors keep their traceback
    in the console only."""
    if isinstance(exc, SESSION_ERRORS):
        msg = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    else:
        traceback.print_exception(exc, file=sys.stderr)
        msg = f"DivAS internal error ({type(exc).__name__}: {exc}); details in the console"
    operator.report({"ERROR"}, msg or type(exc).__name__)
    return {"CANCELLED"}
