"""One exception type for every bad input the engine can meet.

Loaders, camera readers and the CLI raise :class:`DivasInputError` with the
offending file and a plain-language problem, so the CLI and the Blender add-on
can show the message instead of a traceback from deep inside NumPy. Errors a host
may want to explain in its own words carry an :class:`InputErrorCode` and their
numbers in ``details``; the message stays the engine's.
"""

from __future__ import annotations

from enum import StrEnum
from os import PathLike
from typing import Any

__all__ = ["DivasInputError", "InputErrorCode"]


class InputErrorCode(StrEnum):
    """What kind of bad input a :class:`DivasInputError` is (``details`` keys in brackets).

    ``INPUT`` anything else (a file, an option); ``CLICK_OUTSIDE`` a click outside the
    anchor image (``x``, ``y``); ``NO_SURFACE`` nothing under a click (``x``, ``y``);
    ``NO_ANCHOR`` no anchor of that number (``anchor``, ``anchors``); ``VIEW_ACCEPTED`` a
    step on a view already accepted (``view``); ``VIEW_FINISHED`` a view of a finished
    object (``view``); ``FUSION_FULL`` the fusion holds its most views (``views``);
    ``OTHER_SCENE`` a saved session of another scene; ``OTHER_SCENE_SIZE`` one of a scene
    of another size (``count``); ``TORN_SAVE`` a save whose two files do not match.
    """

    INPUT = "input"
    CLICK_OUTSIDE = "click-outside"
    NO_SURFACE = "no-surface"
    NO_ANCHOR = "no-anchor"
    VIEW_ACCEPTED = "view-accepted"
    VIEW_FINISHED = "view-finished"
    FUSION_FULL = "fusion-full"
    OTHER_SCENE = "other-scene"
    OTHER_SCENE_SIZE = "other-scene-size"
    TORN_SAVE = "torn-save"


class DivasInputError(ValueError):
    """Bad user input: names the file (or entry) and what is wrong with it.

    Attributes:
        source: the file or entry, or None; problem: the engine's message.
        code: the :class:`InputErrorCode`; details: its numbers (keys in the code's doc).
    """

    def __init__(
        self,
        source: str | PathLike | None,
        problem: str,
        *,
        code: InputErrorCode = InputErrorCode.INPUT,
        details: dict[str, Any] | None = None,
    ):
        self.source = None if source is None else str(source)
        self.problem = problem
        self.code = code
        self.details = dict(details or {})
        super().__init__(f"{self.source}: {problem}" if self.source else problem)
