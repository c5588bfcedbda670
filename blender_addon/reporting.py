"""Every message the add-on shows, in plain language: what happened, then what to do.

The engine reports a rejected view as data (:class:`~divas_engine.segment.base.Rejection`:
a :class:`~divas_engine.kinds.RejectReason` with its score and threshold) and a bad input
as a :class:`~divas_engine.errors.DivasInputError` with an
:class:`~divas_engine.errors.InputErrorCode` and its numbers; the tables here turn codes
into sentences an artist can act on, keeping the numbers that help. Anything without a
sentence keeps the engine's text (it names the file and the problem); an unexpected error
says it is one and sends its traceback to the console.
"""

from __future__ import annotations

import sys
import traceback
from os import PathLike
from pathlib import Path
from typing import Any

from divas_engine.errors import DivasInputError, InputErrorCode
from divas_engine.kinds import RejectReason
from divas_engine.segment.base import Rejection
from divas_engine.segment.graph3d.segmenter import NO_SURFACE

__all__ = [
    "USER_ERRORS",
    "SESSION_ERRORS",
    "error_message",
    "advice_message",
    "rejection_message",
    "view_rejection_message",
    "report_failure",
    "report_exception",
]

#: errors caused by the user's files or choices; anything else is a bug and propagates.
USER_ERRORS = (DivasInputError, OSError, ValueError, KeyError)
#: failures of a session step reported as one line (anything else is reported with its
#: type, the traceback going to the console).
SESSION_ERRORS = (*USER_ERRORS, ImportError, RuntimeError)

_NEXT_CLICK = "add a click on the object, or a negative click (Shift+click) where it spilled over"
_NO_SURFACE = (
    "There is nothing solid under that click (background or faint splats): "
    "click on the object itself"
)

#: a sentence per input error code (``{name}``: the error's ``details``).
_ERRORS: dict[InputErrorCode, str] = {
    InputErrorCode.CLICK_OUTSIDE: (
        "That click landed outside the image: click inside the camera frame, on the object"
    ),
    InputErrorCode.NO_SURFACE: _NO_SURFACE,
    InputErrorCode.FUSION_FULL: (
        "This object already holds {views} accepted views, the most one object can: press "
        "Finish Object to start the next one, or Ctrl+Z a view"
    ),
    InputErrorCode.VIEW_ACCEPTED: (
        "This view is already accepted: press Ctrl+Z to take it back, or click another anchor"
    ),
    InputErrorCode.VIEW_FINISHED: (
        "That view belongs to an object you already finished: press Ctrl+Z to go back "
        "to it, or click the next object"
    ),
    InputErrorCode.NO_ANCHOR: (
        "There is no anchor {anchor} (this session has {anchors}, numbered from 0): pick one "
        "of the 'Anchor' cameras in 'DivAS Views'"
    ),
    InputErrorCode.OTHER_SCENE: (
        "The saved session belongs to a different scene file: select the object it was "
        "made on, or Start DivAS to begin a new session"
    ),
    InputErrorCode.OTHER_SCENE_SIZE: (
        "The saved session was made on another scene ({count} splats/voxels): select the "
        "object it was made on, or Start DivAS to begin a new session"
    ),
    InputErrorCode.TORN_SAVE: (
        "The saved session's two files do not match (a save was interrupted): Start "
        "DivAS to begin again, or resume an older copy"
    ),
}

#: a sentence per rejection reason (``{score}``, ``{threshold}``, ``{cause}``).
_REJECTIONS: dict[RejectReason, str] = {
    RejectReason.LOW_SCORE: (
        "The 2D segmenter was unsure about this view (confidence {score:.2f}): " + _NEXT_CLICK
    ),
    RejectReason.NO_POSITIVE_PROMPT: (
        "This view has no click on the object left: click the object (left click), then press Enter"
    ),
    RejectReason.EMPTY_MASK: (
        "The mask covered nothing at the depth of the click: click nearer the middle of "
        "the object, then press Enter"
    ),
    RejectReason.SEGMENTATION_FAILED: (
        "The 2D segmenter failed on this view ({cause}): press Enter to try again, or "
        "Ctrl+Z to take the view back"
    ),
    RejectReason.SEGMENTATION_MISSING: (
        "The 2D segmenter returned nothing for this view: press Enter to try again"
    ),
}


def _fill(template: str, values: dict[str, Any]) -> str | None:
    """``template`` with ``values``; None when one of its numbers is unknown."""
    try:
        return template.format(**{k: v for k, v in values.items() if v is not None})
    except (KeyError, IndexError):
        return None


def error_message(exc: BaseException) -> str:
    """``exc`` in plain language: the sentence of its code, else the engine's text."""
    if isinstance(exc, KeyError) and exc.args:
        return str(exc.args[0])
    if isinstance(exc, DivasInputError) and exc.code in _ERRORS:
        text = _fill(_ERRORS[exc.code], exc.details)
        if text is not None:
            return text
    return str(exc)


def advice_message(advice: str | None) -> str:
    """The segmenter's hint (what to click next when it was unsure; the engine's view
    ``advice``) in the add-on's words: a negative click is Shift+click here."""
    if not advice:
        return ""
    text = _NO_SURFACE if advice == NO_SURFACE else advice
    return text.replace("negative click", "negative click (Shift+click)", 1)


_CLICK_HOLDS = "The spot you clicked stays selected. "


def rejection_message(
    rejection: Rejection | None,
    score: float | None = None,
    advice: str | None = None,
    *,
    reason: str | None = None,
    click_holds: bool = False,
) -> str:
    """Why a view was not added, and what to do next (``rejection``: the engine's, with
    ``reason`` its text — alone for views of sessions saved before rejections were kept;
    ``score``: the view's; ``advice``: the segmenter's own hint, which names the click to
    add when it has one; ``click_holds``: the view's click still holds the spot it was
    made on, :meth:`~divas_engine.session.reader.SessionReader.click_holds`)."""
    text = _rejection_text(rejection, score, advice, reason)
    return _CLICK_HOLDS + text if text and click_holds else text


def view_rejection_message(session, view) -> str:
    """:func:`rejection_message` of a refused ``view`` of ``session``."""
    return rejection_message(
        view.rejection,
        view.score,
        view.advice,
        reason=view.reason,
        click_holds=session.click_holds(view),
    )


def _rejection_text(
    rejection: Rejection | None, score: float | None, advice: str | None, reason: str | None
) -> str:
    if rejection is None and not reason:
        return ""
    if advice:
        sure = "" if score is None or score != score else f" (confidence {score:.2f})"
        return (
            f"The segmenter was unsure about this view{sure}. {advice_message(advice)}, "
            "then press Enter"
        )
    text = None
    if rejection is not None:
        values = {"score": rejection.score, "threshold": rejection.threshold}
        text = _fill(_REJECTIONS[rejection.reason], {**values, "cause": rejection.cause})
    if text is None:
        engine = reason or rejection.message
        return f"This view was not added ({engine}): {_NEXT_CLICK}, then press Enter"
    if "Enter" not in text:
        text += ", then press Enter again"
    return text


def report_failure(operator, exc: BaseException, path: str | PathLike | None = None) -> set[str]:
    """Report ``exc`` as an error on ``operator`` (naming ``path`` if the message does not)."""
    msg = error_message(exc)
    if path is not None and Path(path).name not in msg:
        msg = f"{path}: {msg}"
    operator.report({"ERROR"}, msg)
    return {"CANCELLED"}


def report_exception(operator, exc: BaseException) -> set[str]:
    """One readable ``ERROR`` line on ``operator``; unexpected errors keep their traceback
    in the console only."""
    if isinstance(exc, SESSION_ERRORS):
        msg = error_message(exc)
    else:
        traceback.print_exception(exc, file=sys.stderr)
        msg = (
            f"Something went wrong inside DivAS ({type(exc).__name__}: {exc}). The details "
            "are in the system console; Ctrl+Z undoes the last step"
        )
    operator.report({"ERROR"}, msg or type(exc).__name__)
    return {"CANCELLED"}
