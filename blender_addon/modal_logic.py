"""What the click-to-segment modal does with each event — pure logic, no ``bpy``.

Two steps, each a plain function that tests can drive with synthetic values:

1. :func:`decide` turns one event (type, value, Shift, whether the mouse is over the
   viewport's main region) into a :class:`Key`: LMB → positive click, Shift+LMB / RMB →
   negative click, Enter → accept, Backspace → undo, Esc → leave; navigation and
   everything else pass through to Blender (so the view can still be zoomed and the
   panel used).
2. :func:`plan` combines a click / key with what the scene camera shows (a
   :class:`Target`: an anchor, a centroid view and its status, or no DivAS view) into a
   :class:`Step` the operator executes: spawn a centroid view (positive click on an
   anchor), a negative anchor click, a prompt point on a centroid view, accept, undo,
   leave, or a message saying why nothing happens.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from divas_engine.kinds import ViewStatus

__all__ = [
    "Key",
    "KeyKind",
    "Target",
    "Step",
    "StepKind",
    "decide",
    "plan",
    "target_from_props",
    "HEADER_TEXT",
    "ANCHOR_PROP",
    "VIEW_PROP",
    "OWNER_PROP",
]

#: custom properties of the cameras a session creates (see :mod:`.session_actions`).
ANCHOR_PROP, VIEW_PROP, OWNER_PROP = "divas_anchor", "divas_view", "divas_owner"

HEADER_TEXT = (
    "DivAS — LMB: add (positive)  ·  Shift+LMB / RMB: remove (negative)  ·  "
    "Enter: accept view  ·  Backspace: undo last view  ·  Esc: leave"
)

_ACCEPT_KEYS = {"RET", "NUMPAD_ENTER"}
#: a quick second click arrives as DOUBLE_CLICK instead of PRESS: a click all the same.
_PRESSES = ("PRESS", "DOUBLE_CLICK")
#: events that move the view or are never ours: always passed through.
_NAVIGATION = {
    "MIDDLEMOUSE",
    "WHEELUPMOUSE",
    "WHEELDOWNMOUSE",
    "WHEELINMOUSE",
    "WHEELOUTMOUSE",
    "TRACKPADPAN",
    "TRACKPADZOOM",
    "MOUSEROTATE",
    "MOUSESMARTZOOM",
    "MOUSEMOVE",
    "INBETWEEN_MOUSEMOVE",
    "TIMER",
    "TIMER_REPORT",
    "NDOF_MOTION",
    "WINDOW_DEACTIVATE",
}


class KeyKind(Enum):
    PASS = "pass"  # hand the event to Blender
    IGNORE = "ignore"  # ours, but nothing to do (e.g. a key release)
    CLICK = "click"
    ACCEPT = "accept"
    UNDO = "undo"
    EXIT = "exit"


@dataclass(frozen=True)
class Key:
    kind: KeyKind
    positive: bool = True


def decide(event_type: str, value: str, *, shift: bool = False, in_region: bool = True) -> Key:
    """The meaning of one event for the modal (see the module docstring)."""
    if event_type in _NAVIGATION:
        return Key(KeyKind.PASS)
    if event_type in ("LEFTMOUSE", "RIGHTMOUSE"):
        if not in_region:
            return Key(KeyKind.PASS)  # the panel, the header …: Blender's
        if value not in _PRESSES:
            return Key(KeyKind.IGNORE)
        return Key(KeyKind.CLICK, positive=event_type == "LEFTMOUSE" and not shift)
    if value != "PRESS":
        return (
            Key(KeyKind.IGNORE)
            if event_type in (*_ACCEPT_KEYS, "BACK_SPACE", "ESC")
            else Key(KeyKind.PASS)
        )
    if event_type in _ACCEPT_KEYS:
        return Key(KeyKind.ACCEPT)
    if event_type == "BACK_SPACE":
        return Key(KeyKind.UNDO)
    if event_type == "ESC":
        return Key(KeyKind.EXIT)
    return Key(KeyKind.PASS)


@dataclass(frozen=True)
class Target:
    """What the scene camera shows: an anchor (``anchor``), a centroid view (``view_id``
    with its session ``status``), or neither (``anchor is None and view_id is None``)."""

    anchor: int | None = None
    view_id: str | None = None
    status: ViewStatus | str | None = None

    @property
    def is_view(self) -> bool:
        return self.view_id is not None

    @property
    def is_anchor(self) -> bool:
        return self.view_id is None and self.anchor is not None


def target_from_props(props: dict, status_of=None) -> Target:
    """The :class:`Target` of a camera's custom properties (``status_of(view_id)`` gives a
    view's session status, or None when the session no longer has it)."""
    vid = props.get(VIEW_PROP)
    if vid:
        status = status_of(str(vid)) if status_of is not None else ViewStatus.OPEN
        if status is None:
            return Target()
        return Target(int(props.get(ANCHOR_PROP, -1)), str(vid), status)
    if props.get(ANCHOR_PROP) is not None:
        return Target(int(props[ANCHOR_PROP]))
    return Target()


class StepKind(Enum):
    PASS = "pass"
    NOTHING = "nothing"
    MESSAGE = "message"  # tell the user why nothing happens
    SPAWN = "spawn"  # positive click on an anchor → centroid view
    ANCHOR_NEGATIVE = "anchor_negative"
    PROMPT = "prompt"  # add a point to a centroid view, refresh the preview
    ACCEPT = "accept"
    UNDO = "undo"
    EXIT = "exit"


@dataclass(frozen=True)
class Step:
    kind: StepKind
    anchor: int | None = None
    view_id: str | None = None
    xy: tuple[float, float] | None = None
    positive: bool = True
    message: str = ""


def _is_accepted(target: Target) -> bool:
    """An accepted view takes no more prompts until it is undone (a rejected one does)."""
    return target.status is not None and ViewStatus(target.status).accepted


def _accepted(target: Target) -> str:
    return f"View {target.view_id} is already accepted ({target.status}); Backspace undoes it"


_NO_CAMERA = "Look through a DivAS anchor or view camera (in the 'DivAS Views' collection)"


def plan(key: Key, target: Target, xy: tuple[float, float] | None = None) -> Step:
    """The step for ``key`` while the scene camera shows ``target``; ``xy`` is the clicked
    pixel of that camera's image (None: the click missed the camera frame)."""
    k = key.kind
    if k is KeyKind.PASS:
        return Step(StepKind.PASS)
    if k is KeyKind.IGNORE:
        return Step(StepKind.NOTHING)
    if k is KeyKind.EXIT:
        return Step(StepKind.EXIT)
    if k is KeyKind.UNDO:
        return Step(StepKind.UNDO)
    if k is KeyKind.ACCEPT:
        if target.is_view:
            if _is_accepted(target):
                return Step(StepKind.MESSAGE, message=_accepted(target))
            return Step(StepKind.ACCEPT, target.anchor, target.view_id)
        if target.is_anchor:
            return Step(
                StepKind.MESSAGE,
                message="Click the object on the anchor first, then "
                "press Enter in the view it opens",
            )
        return Step(StepKind.MESSAGE, message=_NO_CAMERA)
    # a click
    if not (target.is_view or target.is_anchor):
        return Step(StepKind.MESSAGE, message=_NO_CAMERA)
    if xy is None:
        return Step(StepKind.MESSAGE, message="Click inside the camera frame")
    if target.is_anchor:
        kind = StepKind.SPAWN if key.positive else StepKind.ANCHOR_NEGATIVE
        return Step(kind, target.anchor, None, xy, key.positive)
    if _is_accepted(target):
        return Step(StepKind.MESSAGE, message=_accepted(target))
    return Step(StepKind.PROMPT, target.anchor, target.view_id, xy, key.positive)
