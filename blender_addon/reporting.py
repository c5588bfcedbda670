"""Every message the add-on shows, in plain language: what happened, then what to do.

Engine errors carry precise but technical text ("click at (3, 4) is outside anchor 0
(320x240)", "channel-1 score 0.003 < 0.5"); :func:`plain_message` rewrites the ones a
session step can raise into a sentence an artist can act on, keeping the numbers that
help. Anything unknown keeps the engine's text (it names the file and the problem);
an unexpected error says it is one and sends its traceback to the console.
"""

from __future__ import annotations

import re
import sys
import traceback
from os import PathLike
from pathlib import Path

from divas_engine.errors import DivasInputError

__all__ = [
    "USER_ERRORS",
    "SESSION_ERRORS",
    "plain_message",
    "advice_message",
    "rejection_message",
    "report_failure",
    "report_exception",
]

#: errors caused by the user's files or choices; anything else is a bug and propagates.
USER_ERRORS = (DivasInputError, OSError, ValueError, KeyError)
#: failures of a session step reported as one line (anything else is reported with its
#: type, the traceback going to the console).
SESSION_ERRORS = (*USER_ERRORS, ImportError, RuntimeError)

_NEXT_CLICK = "add a click on the object, or a negative click (Shift+click) where it spilled over"

#: (pattern on the engine's text, plain message; ``{name}`` = the pattern's groups).
_PLAIN: tuple[tuple[str, str], ...] = (
    (
        r"click at \((?P<x>[^,]+), (?P<y>[^)]+)\) is outside anchor",
        "That click landed outside the image: click inside the camera frame, on the object",
    ),
    (
        r"no surface under the click",
        "There is nothing solid under that click (background or faint splats): "
        "click on the object itself",
    ),
    (
        r"channel-\d+ score (?P<score>[-\d.naif]+) < (?P<min>[\d.]+)",
        "The 2D segmenter was unsure about this view (confidence {score}): " + _NEXT_CLICK,
    ),
    (
        r"no positive prompt",
        "This view has no click on the object left: click the object (left click), "
        "then press Enter",
    ),
    (
        r"empty mask after depth weighting",
        "The mask covered nothing at the depth of the click: click nearer the middle of "
        "the object, then press Enter",
    ),
    (
        r"segmentation failed: (?P<cause>.*)",
        "The 2D segmenter failed on this view ({cause}): press Enter to try again, or "
        "Ctrl+Z to take the view back",
    ),
    (
        r"segmentation result missing",
        "The 2D segmenter returned nothing for this view: press Enter to try again",
    ),
    (
        r"bitmask holds (?P<n>\d+) views",
        "This object already holds {n} accepted views, the most one object can: press "
        "Finish Object to start the next one, or Ctrl+Z a view",
    ),
    (
        r"view \S+ is already accepted",
        "This view is already accepted: press Ctrl+Z to take it back, or click another anchor",
    ),
    (
        r"view \S+ belongs to a finished object",
        "That view belongs to an object you already finished: press Ctrl+Z to go back "
        "to it, or click the next object",
    ),
    (
        r"anchor (?P<i>-?\d+) does not exist \((?P<n>\d+) anchors\)",
        "There is no anchor {i} (this session has {n}, numbered from 0): pick one of "
        "the 'Anchor' cameras in 'DivAS Views'",
    ),
    (
        r"session was saved on a different scene",
        "The saved session belongs to a different scene file: select the object it was "
        "made on, or Start DivAS to begin a new session",
    ),
    (
        r"session was saved on a \S+ scene of (?P<n>\d+) primitives",
        "The saved session was made on another scene ({n} splats/voxels): select the "
        "object it was made on, or Start DivAS to begin a new session",
    ),
    (
        r"torn save",
        "The saved session's two files do not match (a save was interrupted): Start "
        "DivAS to begin again, or resume an older copy",
    ),
)


def plain_message(text: str) -> str:
    """``text`` (an engine or add-on message) in plain language (module docstring)."""
    for pattern, plain in _PLAIN:
        m = re.search(pattern, text)
        if m:
            groups = {k: _number(v) for k, v in m.groupdict().items()}
            return plain.format(**groups)
    return text


def _number(v: str) -> str:
    """Decimals to two places (confidences); integers and text as they are."""
    if re.fullmatch(r"-?\d+", v) or not re.fullmatch(r"-?[\d.]+(e-?\d+)?", v):
        return v
    return f"{float(v):.2f}"


def advice_message(advice: str | None) -> str:
    """The segmenter's hint (what to click next when it was unsure; the engine's view
    ``advice``) in the add-on's words: a negative click is Shift+click here."""
    if not advice:
        return ""
    return plain_message(advice).replace("negative click", "negative click (Shift+click)", 1)


def rejection_message(
    reason: str | None, score: float | None = None, advice: str | None = None
) -> str:
    """Why a view was not added, and what to do next (``reason``: the engine's; ``advice``:
    the segmenter's own hint, which names the click to add when it has one)."""
    if not reason:
        return ""
    if advice:
        sure = "" if score is None or score != score else f" (confidence {score:.2f})"
        return (
            f"The segmenter was unsure about this view{sure}. {advice_message(advice)}, "
            "then press Enter"
        )
    text = plain_message(reason)
    if text == reason:  # an engine reason this table does not know yet
        return f"This view was not added ({reason}): {_NEXT_CLICK}, then press Enter"
    if "press Enter" not in text and "Enter" not in text:
        text += ", then press Enter again"
    return text


def _message(exc: BaseException) -> str:
    if isinstance(exc, KeyError) and exc.args:
        return str(exc.args[0])
    if isinstance(exc, DivasInputError):
        plain = plain_message(exc.problem)
        if plain != exc.problem:
            return plain
    return plain_message(str(exc))


def report_failure(operator, exc: BaseException, path: str | PathLike | None = None) -> set[str]:
    """Report ``exc`` as an error on ``operator`` (naming ``path`` if the message does not)."""
    msg = _message(exc)
    if path is not None and Path(path).name not in msg:
        msg = f"{path}: {msg}"
    operator.report({"ERROR"}, msg)
    return {"CANCELLED"}


def report_exception(operator, exc: BaseException) -> set[str]:
    """One readable ``ERROR`` line on ``operator``; unexpected errors keep their traceback
    in the console only."""
    if isinstance(exc, SESSION_ERRORS):
        msg = _message(exc)
    else:
        traceback.print_exception(exc, file=sys.stderr)
        msg = (
            f"Something went wrong inside DivAS ({type(exc).__name__}: {exc}). The details "
            "are in the system console; Ctrl+Z undoes the last step"
        )
    operator.report({"ERROR"}, msg or type(exc).__name__)
    return {"CANCELLED"}
