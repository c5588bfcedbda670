"""Checking a saved session document before it is replayed.

:func:`check_session_doc` walks everything :func:`~.persistence.load_session` reads —
types, finiteness, ranges, camera dictionaries, view statuses, mask keys and shapes —
and raises one :class:`~divas_engine.errors.DivasInputError` naming the file and the
entry (``objects[0].views[2].d_cam: must be a finite number``), so a tampered or foreign
file never reaches the replay as a ``KeyError`` deep inside it.
"""

from __future__ import annotations

import math
from os import PathLike
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..kinds import RejectReason, ViewStatus
from .config import SessionConfig, config_to_dict
from .records import ClickSource

__all__ = ["check_session_doc"]


class _Bad(Exception):
    def __init__(self, where: str, problem: str):
        super().__init__(f"{where}: {problem}")


def _get(d: Any, key: str, where: str) -> Any:
    if not isinstance(d, dict):
        raise _Bad(where, "must be a JSON object")
    if key not in d:
        raise _Bad(f"{where}.{key}" if where else key, "missing")
    return d[key]


def _int(v: Any, where: str, lo: int = 0, hi: int = 1 << 40) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise _Bad(where, f"must be an integer in {lo}..{hi}, got {_short(v)}")
    return v


def _num(v: Any, where: str) -> float:
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        raise _Bad(where, f"must be a number, got {_short(v)}")
    try:
        f = float(v)
    except OverflowError:
        f = math.inf
    if not math.isfinite(f):
        raise _Bad(where, f"must be finite, got {f}")
    return f


def _nums(v: Any, n: int | None, where: str) -> list[float]:
    if not isinstance(v, list) or (n is not None and len(v) != n):
        raise _Bad(where, f"must be a list of {n or 'some'} numbers, got {_short(v)}")
    return [_num(x, f"{where}[{i}]") for i, x in enumerate(v)]


def _kind(v: Any, tp: type | tuple, where: str, what: str) -> Any:
    if not isinstance(v, tp) or (tp is int and isinstance(v, bool)):
        raise _Bad(where, f"must be {what}, got {_short(v)}")
    return v


def _short(v: Any) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def _rejection(v: Any, where: str) -> None:
    try:
        RejectReason(_get(v, "reason", where))
    except (ValueError, TypeError):
        raise _Bad(f"{where}.reason", f"unknown rejection {_short(v['reason'])}") from None
    for k in ("score", "threshold"):
        if v.get(k) is not None:
            _kind(v[k], (int, float), f"{where}.{k}", "a number or null")
    if v.get("channel") is not None:
        _int(v["channel"], f"{where}.channel", 0, 16)
    _kind(v.get("cause"), (str, type(None)), f"{where}.cause", "a string or null")


def _camera(v: Any, where: str) -> Camera:
    _kind(v, dict, where, "a camera object")
    try:
        return Camera.from_dict(v)
    except (ValueError, KeyError, TypeError, OverflowError) as e:
        raise _Bad(where, str(e)) from None


def _click(c: Any, where: str, n_anchors: int) -> None:
    _int(_get(c, "anchor", where), f"{where}.anchor", 0, max(0, n_anchors - 1))
    _int(_get(c, "index", where), f"{where}.index")
    _nums(_get(c, "xy", where), 2, f"{where}.xy")
    _kind(_get(c, "positive", where), bool, f"{where}.positive", "true or false")
    p = _get(c, "point", where)
    if p is not None:
        _nums(p, 3, f"{where}.point")
    _kind(_get(c, "view", where), (str, type(None)), f"{where}.view", "a view id or null")


def _correction(c: Any, where: str, arrays: dict[str, np.ndarray], size: int | None) -> None:
    _int(_get(c, "index", where), f"{where}.index")
    _kind(_get(c, "positive", where), bool, f"{where}.positive", "true or false")
    _nums(_get(c, "point", where), 3, f"{where}.point")
    if _num(_get(c, "radius", where), f"{where}.radius") <= 0:
        raise _Bad(f"{where}.radius", "must be positive")
    key = _get(c, "patch", where)
    if not isinstance(key, str) or key not in arrays:
        raise _Bad(f"{where}.patch", f"names no array of the session ({_short(key)})")
    a = arrays[key]
    if a.ndim != 1 or a.dtype.kind not in "iu":
        raise _Bad(f"{where}.patch", f"array {key!r} must be 1-D integer, not {a.dtype}{a.shape}")
    if len(a) and (int(a.min()) < 0 or (size is not None and int(a.max()) >= size)):
        raise _Bad(f"{where}.patch", f"array {key!r} indexes outside the scene")
    src = _kind(_get(c, "source", where), dict, f"{where}.source", "an object")
    try:
        ClickSource.from_dict(src)
    except (ValueError, KeyError, TypeError, OverflowError) as e:
        raise _Bad(f"{where}.source", str(e)) from None
    views = _kind(_get(c, "views", where), list, f"{where}.views", "a list")
    for i, x in enumerate(views):
        _kind(x, str, f"{where}.views[{i}]", "a view id")
    _kind(c.get("spawned"), (str, type(None)), f"{where}.spawned", "a view id or null")


def _view(v: Any, where: str, n_anchors: int, arrays: dict[str, np.ndarray]) -> None:
    _kind(v, dict, where, "a view object")
    _kind(_get(v, "id", where), str, f"{where}.id", "a string")
    _int(_get(v, "anchor", where), f"{where}.anchor", 0, max(0, n_anchors - 1))
    _int(_get(v, "click", where), f"{where}.click")
    cam = _camera(_get(v, "camera", where), f"{where}.camera")
    for k in ("d_cam", "depth", "r_init"):
        _num(_get(v, k, where), f"{where}.{k}")
    _nums(_get(v, "target", where), 3, f"{where}.target")
    _nums(_get(v, "xy", where), 2, f"{where}.xy")
    box = _get(v, "box", where)
    if box is not None:
        _nums(box, 4, f"{where}.box")
    _kind(_get(v, "strategy", where), str, f"{where}.strategy", "a string")
    _int(_get(v, "neighbours", where), f"{where}.neighbours")
    try:
        status = ViewStatus(_get(v, "status", where))
    except (ValueError, TypeError):
        raise _Bad(f"{where}.status", f"unknown view status {_short(v['status'])}") from None
    _kind(_get(v, "reason", where), (str, type(None)), f"{where}.reason", "a string or null")
    # the segmenter's hint; absent in older sessions
    _kind(v.get("advice"), (str, type(None)), f"{where}.advice", "a string or null")
    if v.get("rejection") is not None:  # absent in older sessions
        _rejection(v["rejection"], f"{where}.rejection")
    score = _get(v, "score", where)
    if score is not None:
        _num(score, f"{where}.score")
    pts, labels = _get(v, "points", where), _get(v, "labels", where)
    if pts is not None:
        _kind(pts, list, f"{where}.points", "a list of [x, y] points")
        for i, p in enumerate(pts):
            _nums(p, 2, f"{where}.points[{i}]")
        _kind(labels, list, f"{where}.labels", "a list of 0/1 labels")
        if len(labels) != len(pts):
            raise _Bad(f"{where}.labels", f"{len(labels)} labels for {len(pts)} points")
        for i, lab in enumerate(labels):
            _int(lab, f"{where}.labels[{i}]", 0, 1)
    if status == ViewStatus.FUSED:
        key = _get(v, "mask", where)
        if not isinstance(key, str) or key not in arrays:
            raise _Bad(f"{where}.mask", f"names no array of the session ({_short(key)})")
        m = arrays[key]
        if m.shape != (cam.height, cam.width) or m.dtype.kind != "f":
            raise _Bad(
                f"{where}.mask",
                f"array {key!r} is {m.dtype}{list(m.shape)}, the view needs float "
                f"[{cam.height}, {cam.width}]",
            )
        if not np.isfinite(m).all():
            raise _Bad(f"{where}.mask", f"array {key!r} holds NaN/Inf")
        _int(_get(v, "fusion_id", where), f"{where}.fusion_id")


def _object(
    o: Any, where: str, n_anchors: int, arrays: dict[str, np.ndarray], size: int | None
) -> None:
    _kind(o, dict, where, "an object")
    _int(_get(o, "index", where), f"{where}.index")
    _int(_get(o, "label", where), f"{where}.label", 1, (1 << 31) - 1)
    _kind(_get(o, "name", where), str, f"{where}.name", "a string")
    _kind(_get(o, "finished", where), bool, f"{where}.finished", "true or false")
    order = _kind(_get(o, "accept_order", where), list, f"{where}.accept_order", "a list")
    for i, x in enumerate(order):
        _kind(x, str, f"{where}.accept_order[{i}]", "a view id")
    clicks = _kind(_get(o, "clicks", where), dict, f"{where}.clicks", "an object")
    for a, cs in clicks.items():
        if not (a.isascii() and a.isdigit() and len(a) < 10 and int(a) < n_anchors):
            raise _Bad(f"{where}.clicks", f"key {_short(a)} is not an anchor index")
        _kind(cs, list, f"{where}.clicks[{a}]", "a list of clicks")
        for i, c in enumerate(cs):
            _click(c, f"{where}.clicks[{a}][{i}]", n_anchors)
    corrections = o.get("corrections", [])  # absent in older sessions
    _kind(corrections, list, f"{where}.corrections", "a list")
    for i, c in enumerate(corrections):
        _correction(c, f"{where}.corrections[{i}]", arrays, size)
    views = _kind(_get(o, "views", where), list, f"{where}.views", "a list")
    for i, v in enumerate(views):
        _view(v, f"{where}.views[{i}]", n_anchors, arrays)


def _config_numbers(tree: Any, default: Any, where: str) -> None:
    """Numbers where the default config has numbers, and no integer beyond float
    precision (2^53): the config decoder lets a list or a 20-digit integer through to a
    float field, which would reach a kernel launch."""
    if isinstance(tree, dict) and isinstance(default, dict) and set(tree) != {"float"}:
        for k, v in tree.items():
            _config_numbers(v, default.get(k), f"{where}.{k}")
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            d = default[i] if isinstance(default, list) and i < len(default) else None
            _config_numbers(v, d, f"{where}[{i}]")
    elif isinstance(tree, int) and not isinstance(tree, bool) and abs(tree) > 1 << 53:
        raise _Bad(where, f"integer {_short(tree)} is out of range")
    number = (int, float)
    if isinstance(default, number) and not isinstance(default, bool):
        ok = (
            tree is None  # an Optional field: the decoder checked that None is allowed
            or (isinstance(tree, number) and not isinstance(tree, bool))
            or (isinstance(tree, dict) and set(tree) == {"float"})
        )
        if not ok:
            raise _Bad(where, f"must be a number, got {_short(tree)}")


def check_session_doc(
    path: str | PathLike, doc: dict[str, Any], arrays: dict[str, np.ndarray]
) -> SessionConfig:
    """Validate a loaded session document; returns its config.

    Raises:
        DivasInputError: naming ``path`` and the first bad entry.
    """
    try:
        try:
            config = SessionConfig.from_dict(_kind(_get(doc, "config", ""), dict, "config", "{}"))
        except _Bad:
            raise
        except (ValueError, TypeError, KeyError, OverflowError) as e:
            raise _Bad("config", str(e)) from None
        _config_numbers(config_to_dict(config), config_to_dict(SessionConfig()), "config")
        sd = _kind(_get(doc, "scene", ""), dict, "scene", "an object")
        _kind(_get(sd, "kind", "scene"), str, "scene.kind", "a string")
        _int(_get(sd, "count", "scene"), "scene.count")
        fp = sd.get("fingerprint")
        _kind(fp, (str, type(None)), "scene.fingerprint", "a string or null")
        _kind(_get(doc, "forward_facing", ""), bool, "forward_facing", "true or false")
        anchors = _kind(_get(doc, "anchors", ""), list, "anchors", "a list")
        for i, a in enumerate(anchors):
            w = f"anchors[{i}]"
            _camera(_get(a, "camera", w), f"{w}.camera")
            _kind(_get(a, "source", w), str, f"{w}.source", "a string")
            _int(_get(a, "index", w), f"{w}.index", -1)
        objs = _kind(_get(doc, "objects", ""), list, "objects", "a list")
        size = arrays["labels"].size if "labels" in arrays else None
        for i, o in enumerate(objs):
            _object(o, f"objects[{i}]", len(anchors), arrays, size)
        for key in ("labels", "selection"):
            if key in arrays and arrays[key].dtype.kind not in "biu":
                raise _Bad(
                    f"arrays[{key!r}]", f"must be integer or boolean, not {arrays[key].dtype}"
                )
    except _Bad as e:
        raise DivasInputError(path, f"bad session file: {e}") from None
    return config
