"""The headless prompts file (NOTES "Headless prompts file", version 1).

::

    {"version": 1,
     "anchors": [
       {"camera": {<Camera.to_dict schema, OpenCV c2w>}, "clicks": [{"xy": [x, y]}, ...]},
       {"training_camera": "IMG_0012", "clicks": [{"xy": [x, y]}]},
       {"fibonacci": 2, "clicks": [{"xy": [x, y], "positive": false}]}],
     "centroid_prompts": {"0:1": [{"xy": [x, y], "positive": false}]},
     "points": [{"xyz": [x, y, z]}, {"xyz": [x, y, z], "positive": false}]}

Each positive click spawns a centroid view; a negative click is a correction of the object
(``docs/corrections.md``); ``points`` are 3D prompts placed on anchors by the engine. Errors
raise :class:`~divas_engine.errors.DivasInputError` naming the entry
(``anchors[1].clicks[0].xy``); :func:`parse_prompts` checks the syntax, :func:`resolve_anchors`
names, indices and image bounds. The rules in full: docs/design-notes.md and docs/prompts-file.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

from ..camera import Camera
from ..errors import DivasInputError
from ..io.json_file import read_json
from ..io.limits import limits
from ..output_paths import write_json_atomic

__all__ = [
    "PROMPTS_VERSION",
    "Click",
    "PointPrompt",
    "AnchorPrompt",
    "Prompts",
    "ResolvedAnchor",
    "parse_prompts",
    "load_prompts",
    "resolve_anchors",
    "find_training_camera",
]

PROMPTS_VERSION = 1
_TOP_KEYS = {"version", "anchors", "centroid_prompts", "points"}
_ANCHOR_KINDS = ("camera", "training_camera", "fibonacci")
_CLICK_KEYS = {"xy", "positive"}
_POINT_KEYS = {"xyz", "positive", "radius"}


@dataclass(frozen=True)
class Click:
    """A point prompt: continuous pixel ``xy`` and its label."""

    xy: tuple[float, float]
    positive: bool = True

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"xy": [self.xy[0], self.xy[1]]}
        if not self.positive:
            d["positive"] = False
        return d


@dataclass(frozen=True)
class PointPrompt:
    """A prompt in 3D: world point ``xyz`` (the scene's frame), its label, and how far
    inside its object it may lie (``radius``, scene units: an object's centre)."""

    xyz: tuple[float, float, float]
    positive: bool = True
    radius: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"xyz": list(self.xyz)}
        if not self.positive:
            d["positive"] = False
        if self.radius:
            d["radius"] = self.radius
        return d


@dataclass(frozen=True)
class AnchorPrompt:
    """One anchor entry: how the anchor camera is given, and its clicks."""

    kind: str
    value: Any  # Camera | str | int
    clicks: tuple[Click, ...]

    def to_dict(self) -> dict[str, Any]:
        v = self.value.to_dict() if isinstance(self.value, Camera) else self.value
        return {self.kind: v, "clicks": [c.to_dict() for c in self.clicks]}


@dataclass(frozen=True)
class Prompts:
    """A parsed prompts file."""

    anchors: tuple[AnchorPrompt, ...]
    centroid_prompts: dict[tuple[int, int], tuple[Click, ...]] = field(default_factory=dict)
    source: str | None = None
    points: tuple[PointPrompt, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "version": PROMPTS_VERSION,
            "anchors": [a.to_dict() for a in self.anchors],
            "centroid_prompts": {
                f"{a}:{c}": [p.to_dict() for p in pts]
                for (a, c), pts in self.centroid_prompts.items()
            },
        }
        if self.points:
            d["points"] = [p.to_dict() for p in self.points]
        return d

    def write(self, path: str | PathLike) -> None:
        write_json_atomic(path, self.to_dict())

    def extra_points(self, anchor: int, click: int) -> tuple[Click, ...]:
        return self.centroid_prompts.get((anchor, click), ())


def _fail(src: str | None, where: str, problem: str) -> DivasInputError:
    return DivasInputError(src, f"{where}: {problem}")


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _parse_click(d: Any, where: str, src: str | None) -> Click:
    if not isinstance(d, dict):
        raise _fail(src, where, f'must be an object like {{"xy": [x, y]}}, got {type(d).__name__}')
    unknown = set(d) - _CLICK_KEYS
    if unknown:
        raise _fail(src, where, f"unknown keys {sorted(unknown)} (allowed: xy, positive)")
    if "xy" not in d:
        raise _fail(src, where, "missing 'xy'")
    xy = d["xy"]
    if not (isinstance(xy, list) and len(xy) == 2 and all(_number(v) for v in xy)):
        raise _fail(src, f"{where}.xy", f"must be two finite numbers [x, y], got {xy!r}")
    pos = d.get("positive", True)
    if not isinstance(pos, bool):
        raise _fail(src, f"{where}.positive", f"must be true or false, got {pos!r}")
    return Click((float(xy[0]), float(xy[1])), pos)


def _parse_point(d: Any, where: str, src: str | None) -> PointPrompt:
    if not isinstance(d, dict):
        raise _fail(
            src, where, f'must be an object like {{"xyz": [x, y, z]}}, got {type(d).__name__}'
        )
    unknown = set(d) - _POINT_KEYS
    if unknown:
        raise _fail(src, where, f"unknown keys {sorted(unknown)} (allowed: xyz, positive, radius)")
    xyz = d.get("xyz")
    if not (isinstance(xyz, list) and len(xyz) == 3 and all(_number(v) for v in xyz)):
        raise _fail(src, f"{where}.xyz", f"must be three finite numbers [x, y, z], got {xyz!r}")
    pos = d.get("positive", True)
    if not isinstance(pos, bool):
        raise _fail(src, f"{where}.positive", f"must be true or false, got {pos!r}")
    r = d.get("radius", 0.0)
    if not (_number(r) and r >= 0):
        raise _fail(src, f"{where}.radius", f"must be a finite number ≥ 0, got {r!r}")
    return PointPrompt((float(xyz[0]), float(xyz[1]), float(xyz[2])), pos, float(r))


def _parse_clicks(v: Any, where: str, src: str | None) -> tuple[Click, ...]:
    if not isinstance(v, list):
        raise _fail(src, where, f"must be a list of clicks, got {type(v).__name__}")
    return tuple(_parse_click(c, f"{where}[{i}]", src) for i, c in enumerate(v))


def _parse_anchor(d: Any, i: int, src: str | None) -> AnchorPrompt:
    where = f"anchors[{i}]"
    if not isinstance(d, dict):
        raise _fail(src, where, f"must be an object, got {type(d).__name__}")
    unknown = set(d) - set(_ANCHOR_KINDS) - {"clicks"}
    if unknown:
        raise _fail(
            src,
            where,
            f"unknown keys {sorted(unknown)} (allowed: camera, training_camera, fibonacci, clicks)",
        )
    kinds = [k for k in _ANCHOR_KINDS if k in d]
    if len(kinds) != 1:
        raise _fail(
            src,
            where,
            "needs exactly one of 'camera', 'training_camera', 'fibonacci'"
            f" (got {kinds or 'none'})",
        )
    kind = kinds[0]
    v = d[kind]
    if kind == "camera":
        if not isinstance(v, dict):
            raise _fail(src, f"{where}.camera", "must be a camera object")
        try:
            value: Any = Camera.from_dict(v)
        except (ValueError, KeyError, TypeError, OverflowError) as e:
            raise _fail(src, f"{where}.camera", str(e)) from None
        if value.fx <= 0 or value.width <= 0:
            raise _fail(src, f"{where}.camera", "bad intrinsics")
    elif kind == "training_camera":
        if not isinstance(v, str) or not v:
            raise _fail(src, f"{where}.training_camera", f"must be a camera name, got {v!r}")
        value = v
    else:
        if not (isinstance(v, int) and not isinstance(v, bool)) or v < 0:
            raise _fail(src, f"{where}.fibonacci", f"must be a non-negative integer, got {v!r}")
        value = int(v)
    if "clicks" not in d:
        raise _fail(src, where, "missing 'clicks'")
    clicks = _parse_clicks(d["clicks"], f"{where}.clicks", src)
    if not clicks:
        raise _fail(src, f"{where}.clicks", "must hold at least one click")
    return AnchorPrompt(kind, value, clicks)


def _check_click_count(doc: dict, src: str | None) -> None:
    """At most ``LoadLimits.max_clicks`` clicks in the file (each one is a view to render)."""
    n = 0
    for a in doc.get("anchors") or ():
        if isinstance(a, dict) and isinstance(a.get("clicks"), list):
            n += len(a["clicks"])
    cp = doc.get("centroid_prompts")
    if isinstance(cp, dict):
        n += sum(len(v) for v in cp.values() if isinstance(v, list))
    if isinstance(doc.get("points"), list):
        n += len(doc["points"])
    cap = limits().max_clicks
    if n > cap:
        raise DivasInputError(src, f"{n} clicks, more than the {cap} a prompts file may hold")


def parse_prompts(doc: Any, source: str | PathLike | None = None) -> Prompts:
    """Check and parse a prompts document (already decoded JSON)."""
    src = None if source is None else str(source)
    if not isinstance(doc, dict):
        raise DivasInputError(
            src, f"prompts file must hold a JSON object, got {type(doc).__name__}"
        )
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        raise DivasInputError(
            src,
            f"unknown top-level keys {sorted(unknown)} "
            "(allowed: version, anchors, centroid_prompts, points)",
        )
    if doc.get("version") != PROMPTS_VERSION:
        raise _fail(src, "version", f"must be {PROMPTS_VERSION}, got {doc.get('version')!r}")
    points_doc = doc.get("points", [])
    if not isinstance(points_doc, list):
        raise _fail(src, "points", 'must be a list of points like {"xyz": [x, y, z]}')
    anchors_doc = doc.get("anchors", [] if points_doc else None)
    if not isinstance(anchors_doc, list) or not (anchors_doc or points_doc):
        raise _fail(src, "anchors", "must be a non-empty list of anchors (or give 'points')")
    _check_click_count(doc, src)
    anchors = tuple(_parse_anchor(a, i, src) for i, a in enumerate(anchors_doc))
    points = tuple(_parse_point(p, f"points[{i}]", src) for i, p in enumerate(points_doc))
    cp_doc = doc.get("centroid_prompts", {})
    if not isinstance(cp_doc, dict):
        raise _fail(src, "centroid_prompts", 'must be an object keyed "anchor:click"')
    cps: dict[tuple[int, int], tuple[Click, ...]] = {}
    for key, pts in cp_doc.items():
        where = f"centroid_prompts[{key!r}]"
        parts = key.split(":")
        if len(parts) != 2 or not all(p.isascii() and p.isdigit() and len(p) < 10 for p in parts):
            raise _fail(src, where, 'key must be "anchor:click" with two non-negative integers')
        a, c = int(parts[0]), int(parts[1])
        if a >= len(anchors):
            raise _fail(src, where, f"anchor {a} does not exist ({len(anchors)} anchors)")
        if c >= len(anchors[a].clicks):
            raise _fail(
                src, where, f"anchor {a} has no click {c} ({len(anchors[a].clicks)} clicks)"
            )
        if not anchors[a].clicks[c].positive:
            raise _fail(
                src, where, f"click {c} of anchor {a} is negative and spawns no centroid view"
            )
        cps[(a, c)] = _parse_clicks(pts, where, src)
    return Prompts(anchors, cps, src, points)


def load_prompts(path: str | PathLike) -> Prompts:
    """Read and parse a prompts file."""
    path = Path(path)
    return parse_prompts(read_json(path, "prompts file"), path)


def find_training_camera(cameras: list[Camera], name: str) -> int | None:
    """Index of the training camera called ``name`` (image extension optional on both sides)."""
    names = [c.name for c in cameras]
    if name in names:
        return names.index(name)
    stem = Path(name).stem if Path(name).suffix else name
    stems = [Path(n).stem if Path(n).suffix else n for n in names]
    hits = [i for i, s in enumerate(stems) if s == stem]
    return hits[0] if len(hits) == 1 else None


@dataclass(frozen=True)
class ResolvedAnchor:
    """A prompts-file anchor turned into a camera (full resolution)."""

    camera: Camera
    source: str  # "camera" | "training" | "fibonacci"
    index: int  # training-camera / Fibonacci index, -1 for explicit cameras
    prompt: AnchorPrompt
    points: tuple[int, ...] | None = None  # per click, the 3D point it comes from

    def where(self, anchor: int, click: int) -> str:
        """How click ``click`` of this anchor (number ``anchor``) is named in errors."""
        if self.points is not None:
            return f"points[{self.points[click]}]"
        return f"anchors[{anchor}].clicks[{click}]"


def _check_in_image(cam: Camera, xy: tuple[float, float], where: str, src: str | None) -> None:
    x, y = xy
    if not (0.0 <= x < cam.width and 0.0 <= y < cam.height):
        raise _fail(
            src, where, f"point ({x:g}, {y:g}) is outside the {cam.width}x{cam.height} image"
        )


def resolve_anchors(
    prompts: Prompts, cameras: list[Camera], fibonacci: Callable[[], list[Camera]] | None = None
) -> list[ResolvedAnchor]:
    """Anchor cameras of ``prompts``; checks names, indices and that every click is in its image.

    ``fibonacci``: returns the N Fibonacci candidate cameras (called once, on demand).
    """
    src = prompts.source
    fib: list[Camera] | None = None
    out: list[ResolvedAnchor] = []
    for i, a in enumerate(prompts.anchors):
        where = f"anchors[{i}]"
        if a.kind == "camera":
            cam, source, idx = a.value, "camera", -1
        elif a.kind == "training_camera":
            if not cameras:
                raise _fail(
                    src,
                    f"{where}.training_camera",
                    "the scene has no training cameras (pass --cameras)",
                )
            j = find_training_camera(cameras, a.value)
            if j is None:
                sample = ", ".join(c.name for c in cameras[:5])
                raise _fail(
                    src,
                    f"{where}.training_camera",
                    f"no training camera named {a.value!r} (have e.g. {sample})",
                )
            cam, source, idx = cameras[j], "training", j
        else:
            if fib is None:
                if fibonacci is None:
                    raise _fail(src, f"{where}.fibonacci", "Fibonacci anchors are not available")
                fib = fibonacci()
            if a.value >= len(fib):
                raise _fail(
                    src, f"{where}.fibonacci", f"index {a.value} out of range 0..{len(fib) - 1}"
                )
            cam, source, idx = fib[a.value], "fibonacci", a.value
        for k, c in enumerate(a.clicks):
            _check_in_image(cam, c.xy, f"{where}.clicks[{k}].xy", src)
        out.append(ResolvedAnchor(cam, source, idx, a))
    for (ai, ci), pts in prompts.centroid_prompts.items():
        cam = out[ai].camera  # a centroid view keeps its anchor's intrinsics
        for k, p in enumerate(pts):
            _check_in_image(cam, p.xy, f"centroid_prompts['{ai}:{ci}'][{k}].xy", src)
    return out
