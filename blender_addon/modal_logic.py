"""What the click-to-segment modal does with each event — pure logic, no ``bpy``.

Two steps, each a plain function that tests can drive with synthetic values:

1. :func:`decide` turns one event (type, value, Shift, Ctrl, whether the mouse is over
   the viewport's main region) into a :class:`Key`: LMB → positive click, Shift+LMB /
   RMB → negative click, Enter → accept, Ctrl+Z / Backspace → undo, Ctrl+Shift+Z →
   redo (Blender's own undo, which the session follows), Esc → leave; navigation and
   everything else pass through to Blender (so the view can still be orbited, zoomed
   and the panel used).
2. :func:`plan` combines a click / key with what the view shows (a :class:`Target`:
   through an anchor camera, through a centroid view's camera with its status, or a
   free 3D view) into a :class:`Step` the operator executes: spawn a centroid view
   (positive click on an anchor), a negative anchor click, a prompt point on an open
   centroid view, a correction on an accepted one (the click a 3D constraint:
   :mod:`divas_engine.session.corrections`), a click in a free view (the view becomes
   an anchor), accept, undo, redo, leave, or a message saying why nothing happens.

:class:`Gesture` is the same for the box / lasso / brush selection modal.
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
    "Gesture",
    "GestureAction",
    "gesture_mode",
    "target_from_props",
    "HEADER_TEXT",
    "ANCHOR_PROP",
    "VIEW_PROP",
    "OWNER_PROP",
]

#: custom properties of the cameras a session creates (see :mod:`.session_actions`).
ANCHOR_PROP, VIEW_PROP, OWNER_PROP = "divas_anchor", "divas_view", "divas_owner"

HEADER_TEXT = (
    "DivAS — click the object (any view)  ·  LMB: add  ·  Shift+LMB / RMB: remove  ·  "
    "Enter: accept  ·  Ctrl+Z: undo  ·  Ctrl+Shift+Z: redo  ·  Esc: leave"
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
    REDO = "redo"
    EXIT = "exit"


@dataclass(frozen=True)
class Key:
    kind: KeyKind
    positive: bool = True


def decide(
    event_type: str,
    value: str,
    *,
    shift: bool = False,
    in_region: bool = True,
    ctrl: bool = False,
) -> Key:
    """The meaning of one event for the modal (see the module docstring)."""
    if event_type in _NAVIGATION:
        return Key(KeyKind.PASS)
    if event_type in ("LEFTMOUSE", "RIGHTMOUSE"):
        if not in_region:
            return Key(KeyKind.PASS)  # the panel, the header …: Blender's
        if value not in _PRESSES:
            return Key(KeyKind.IGNORE)
        return Key(KeyKind.CLICK, positive=event_type == "LEFTMOUSE" and not shift)
    if event_type == "Z" and ctrl:
        if value != "PRESS":
            return Key(KeyKind.IGNORE)
        return Key(KeyKind.REDO if shift else KeyKind.UNDO)
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
    """What the view shows: through an anchor camera (``anchor``), through a centroid
    view's camera (``view_id`` with its session ``status``), a free 3D view (``free``:
    a click there turns the view into an anchor), or none of these."""

    anchor: int | None = None
    view_id: str | None = None
    status: ViewStatus | str | None = None
    free: bool = False

    @property
    def is_view(self) -> bool:
        return self.view_id is not None

    @property
    def is_anchor(self) -> bool:
        return self.view_id is None and self.anchor is not None

    @property
    def is_free(self) -> bool:
        return self.free and self.view_id is None and self.anchor is None


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
    CORRECT_VIEW = "correct_view"  # a click on an accepted view: a correction
    VIEWPORT_CLICK = "viewport_click"  # a click in a free 3D view → an anchor of it
    ACCEPT = "accept"
    UNDO = "undo"
    REDO = "redo"
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
    return (
        "This view is already accepted: click it to correct the selection (Shift: remove), "
        "Ctrl+Z takes it back"
    )


_NO_CAMERA = (
    "This is not a view DivAS can use: look through a DivAS camera, or leave the "
    "camera view (Numpad 0) and click the object in the 3D view"
)


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
    if k is KeyKind.REDO:
        return Step(StepKind.REDO)
    if k is KeyKind.ACCEPT:
        if target.is_view:
            if _is_accepted(target):
                return Step(StepKind.MESSAGE, message=_accepted(target))
            return Step(StepKind.ACCEPT, target.anchor, target.view_id)
        if target.is_anchor:
            return Step(
                StepKind.MESSAGE,
                message="Nothing to accept yet: click the object on this anchor first, "
                "then press Enter in the close-up view it opens",
            )
        if target.is_free:
            return Step(StepKind.ACCEPT)  # the next open view, if any
        return Step(StepKind.MESSAGE, message=_NO_CAMERA)
    # a click
    if target.is_free:
        if xy is None:
            return Step(StepKind.MESSAGE, message="Click inside the 3D view")
        return Step(StepKind.VIEWPORT_CLICK, None, None, xy, key.positive)
    if not (target.is_view or target.is_anchor):
        return Step(StepKind.MESSAGE, message=_NO_CAMERA)
    if xy is None:
        return Step(
            StepKind.MESSAGE,
            message="That click missed the camera's image: click inside the camera frame",
        )
    if target.is_anchor:
        kind = StepKind.SPAWN if key.positive else StepKind.ANCHOR_NEGATIVE
        return Step(kind, target.anchor, None, xy, key.positive)
    kind = StepKind.CORRECT_VIEW if _is_accepted(target) else StepKind.PROMPT
    return Step(kind, target.anchor, target.view_id, xy, key.positive)


# ----------------------------------------------------------------------------- gestures
def gesture_mode(shift: bool, ctrl: bool) -> str:
    """Blender's convention: plain → SET, Shift → ADD, Ctrl → SUB, Shift+Ctrl → AND."""
    if shift and ctrl:
        return "AND"
    if ctrl:
        return "SUB"
    return "ADD" if shift else "SET"


@dataclass(frozen=True)
class GestureAction:
    """What the gesture modal does after one event: ``kind`` is ``"pass"``, ``"none"``
    (redraw), ``"apply"`` (select ``points`` as ``shape`` in ``mode``; ``final``: the
    gesture is over), ``"cancel"``."""

    kind: str
    shape: str = ""
    points: tuple[tuple[float, float], ...] = ()
    mode: str = "SET"
    radius: float = 0.0
    final: bool = False


class Gesture:
    """Box, lasso or brush (``CIRCLE``) in region pixels, from raw events (pure).

    Box and lasso: press starts, moves extend, release selects once. Brush: every
    move while pressed selects a disc (``ADD``, or ``SUB`` with Ctrl) and the release
    ends the stroke; the wheel or +/- changes the radius. Esc / RMB cancel."""

    def __init__(self, shape: str, radius: float = 25.0) -> None:
        self.shape, self.radius = shape, float(radius)
        self.points: list[tuple[float, float]] = []
        self.pressed = False
        self.mode = "SET"

    def feed(self, event_type, value, x, y, *, shift=False, ctrl=False) -> GestureAction:
        xy = (float(x), float(y))
        if event_type in ("ESC", "RIGHTMOUSE") and value == "PRESS":
            return GestureAction("cancel")
        if self.shape == "CIRCLE" and event_type in ("WHEELUPMOUSE", "NUMPAD_PLUS"):
            self.radius *= 1.2
            return GestureAction("none")
        if self.shape == "CIRCLE" and event_type in ("WHEELDOWNMOUSE", "NUMPAD_MINUS"):
            self.radius = max(2.0, self.radius / 1.2)
            return GestureAction("none")
        if event_type == "LEFTMOUSE" and value == "PRESS":
            self.pressed, self.points = True, [xy]
            self.mode = gesture_mode(shift, ctrl)
            if self.shape == "CIRCLE":
                self.mode = "SUB" if ctrl else "ADD"
                return self._disc(xy, final=False)
            return GestureAction("none")
        if event_type in ("MOUSEMOVE", "INBETWEEN_MOUSEMOVE"):
            if not self.pressed:
                if self.shape == "CIRCLE":
                    self.points = [xy]  # the brush follows the mouse
                return GestureAction("none")
            if self.shape == "CIRCLE":
                self.points = [xy]
                return self._disc(xy, final=False)
            if self.shape == "BOX":
                self.points = [self.points[0], xy]
            elif xy != self.points[-1]:
                self.points.append(xy)
            return GestureAction("none")
        if event_type == "LEFTMOUSE" and value == "RELEASE" and self.pressed:
            self.pressed = False
            if self.shape == "CIRCLE":
                return GestureAction("apply", "CIRCLE", (), self.mode, self.radius, final=True)
            if self.shape == "BOX" and len(self.points) == 2:
                return GestureAction("apply", "BOX", tuple(self.points), self.mode, final=True)
            if self.shape == "LASSO" and len(self.points) >= 3:
                return GestureAction("apply", "LASSO", tuple(self.points), self.mode, final=True)
            return GestureAction("cancel")
        return GestureAction("pass")

    def _disc(self, xy, *, final: bool) -> GestureAction:
        return GestureAction("apply", "CIRCLE", (xy,), self.mode, self.radius, final)
