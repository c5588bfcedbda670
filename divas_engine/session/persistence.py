"""A session as a saved document and back (the file layer is :mod:`.store`).

:func:`session_document` turns a :class:`~divas_engine.session.Session` into the JSON
document plus the arrays (the accepted, depth-weighted masks, the segmenter's raw
masks the 3DGS completion reads, the clicks' surface patches, the labels and the
selection); :func:`load_session`
parses them back into plain records (:func:`saved_object`) and has a new session
*replay* them (:meth:`~divas_engine.session.Session.replay`): the stored camera poses are
re-rendered and the stored masks fused in their slots, so the replayed labels equal the
saved ones without running SAM again. Views that were still pending (NeRF) are
re-submitted to the segmenter.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import replace
from os import PathLike
from typing import TYPE_CHECKING, Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError, InputErrorCode
from ..io.limits import PARSE_ERRORS, input_guard
from ..kinds import ViewStatus
from ..scene import Scene
from ..segment.base import Rejection, Segmenter
from ..views.centroid_common import CentroidView
from .backends import backend_class_for
from .edits import edit_arrays, saved_edits
from .records import AnchorClick, ClickSource, Correction, ObjectRecord, SessionView
from .store import SESSION_FORMAT, SESSION_VERSION, load_state
from .validate import check_session_doc

if TYPE_CHECKING:
    from .session import Session

__all__ = ["scene_fingerprint", "session_document", "load_session", "saved_object"]


def scene_fingerprint(scene: Scene) -> str:
    """Hash of the array that identifies ``scene`` (its backend's ``fingerprint_array``)."""
    h = hashlib.blake2b(digest_size=16)
    a = np.ascontiguousarray(backend_class_for(scene).fingerprint_array(scene))
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def session_document(session: Session) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The saved document and arrays of ``session``."""
    arrays: dict[str, np.ndarray] = {}
    objs = []
    for o in session.objects:
        vdocs = []
        for v in o.views:
            key = raw_key = None
            if v.status == ViewStatus.FUSED and v.mask is not None:
                key = f"mask_{len(arrays)}"
                arrays[key] = v.mask.astype(np.float32)
                raw = v.preview.selection.mask if v.preview is not None else v.raw_mask
                if raw is not None:  # the 3DGS completion's evidence (the raw mask)
                    raw_key = f"raw_{len(arrays)}"
                    arrays[raw_key] = np.asarray(raw, np.float32)
            vd = v.to_dict(key)
            vd["raw_mask"] = raw_key
            vdocs.append(vd)
        objs.append(
            {
                "index": o.index,
                "label": o.label,
                "name": o.name,
                "finished": o.finished,
                "accept_order": list(o.accept_order),
                "clicks": {str(a): [c.to_dict() for c in cs] for a, cs in o.clicks.items()},
                "corrections": [_correction_doc(c, o.index, arrays) for c in o.corrections],
                "views": vdocs,
            }
        )
    arrays.update(edit_arrays(session.edits))
    arrays["labels"] = session.label_set(include_current=False)
    arrays["selection"] = session.selection
    scene = session.scene
    doc = {
        "format": SESSION_FORMAT,
        "version": SESSION_VERSION,
        "scene": {
            "kind": session.kind,
            "count": int(len(scene)),
            "fingerprint": scene_fingerprint(scene),
            "path": None if getattr(scene, "source", None) is None else str(scene.source.path),
        },
        "config": session.config.to_dict(),
        "forward_facing": session.forward_facing,
        "anchors": [
            {"camera": a.full_camera.to_dict(), "source": a.source, "index": a.source_index}
            for a in session.anchors
        ],
        "objects": objs,
    }
    return doc, arrays


def _correction_doc(c: Correction, obj_index: int, arrays: dict[str, np.ndarray]) -> dict:
    key = f"patch_{obj_index}_{c.index}"
    arrays[key] = np.asarray(c.patch, np.int64)
    return c.to_dict(key)


def load_session(
    session_cls: type[Session],
    path: str | PathLike,
    scene: Scene,
    segmenter: Segmenter | None = None,
    device=None,
    *,
    cameras: Sequence[Camera] | None = None,
    gt_values: np.ndarray | None = None,
    autosave: str | None | bool = False,
) -> Session:
    """``Session.load``: rebuild a saved session on ``scene`` by replaying it (stored poses
    re-rendered, stored masks fused, mapping re-run); NeRF views still pending when it was
    saved are re-submitted to ``segmenter``. ``replay_matches`` tells whether the replayed
    labels equal the saved ones. ``autosave``: False keeps it off while loading and after;
    a path (or None) overrides the saved config's."""
    with input_guard(path, "session file"):
        doc, arrays = load_state(path)
    config = check_session_doc(path, doc, arrays)
    try:
        return _replay(
            session_cls,
            path,
            doc,
            arrays,
            config,
            scene,
            segmenter,
            device,
            cameras,
            gt_values,
            autosave,
        )
    except DivasInputError as e:
        if e.source is None:  # a check deep in the replay that does not know the file
            raise DivasInputError(
                path, f"bad session file: {e.problem}", code=e.code, details=e.details
            ) from None
        raise
    except PARSE_ERRORS as e:  # validated above; whatever still fails comes from the file
        raise DivasInputError(
            path, f"bad session file: replay failed ({type(e).__name__}: {e})"
        ) from e


def _replay(
    session_cls, path, doc, arrays, config, scene, segmenter, device, cameras, gt_values, autosave
) -> Session:
    final_autosave = config.autosave if autosave is False else autosave
    config = replace(config, autosave=None)
    sd = doc["scene"]
    if sd["kind"] != backend_class_for(scene).kind or sd["count"] != len(scene):
        raise DivasInputError(
            path,
            f"session was saved on a {sd['kind']} scene of {sd['count']} primitives, not this one",
            code=InputErrorCode.OTHER_SCENE_SIZE,
            details={"count": sd["count"]},
        )
    if sd.get("fingerprint") and sd["fingerprint"] != scene_fingerprint(scene):
        raise DivasInputError(
            path,
            "session was saved on a different scene (fingerprint mismatch)",
            code=InputErrorCode.OTHER_SCENE,
        )
    anchors = [
        (Camera.from_dict(a["camera"]), a["source"], int(a["index"])) for a in doc["anchors"]
    ]
    s = session_cls(
        scene,
        cameras,
        config,
        segmenter,
        device,
        anchors,
        bool(doc["forward_facing"]),
        gt_values=gt_values,
    )
    objects = [saved_object(od, arrays, path) for od in doc["objects"]]
    edits = saved_edits(arrays, s.backend.selection_shape, [o.index for o in objects])
    s.replay(objects, edits)
    saved = arrays.get("labels")
    s.replay_matches = bool(
        saved is not None
        and np.array_equal(saved, s.labels)
        and np.array_equal(arrays.get("selection"), s.selection)
    )
    s.config = replace(s.config, autosave=None if final_autosave is None else str(final_autosave))
    return s


def _view_status(value: Any, path: str | PathLike | None) -> ViewStatus:
    try:
        return ViewStatus(value)
    except ValueError:
        raise DivasInputError(path, f"unknown view status {value!r} in the session") from None


def saved_object(
    od: dict[str, Any], arrays: dict[str, np.ndarray], path: str | PathLike | None = None
) -> ObjectRecord:
    """One saved object as plain records: its clicks and views (fused views with their
    mask and slot, as saved)."""
    obj = ObjectRecord(int(od["index"]), int(od["label"]), str(od["name"]))
    obj.finished = bool(od["finished"])
    for a, cs in od["clicks"].items():
        obj.clicks[int(a)] = [
            AnchorClick(
                int(c["anchor"]),
                int(c["index"]),
                (float(c["xy"][0]), float(c["xy"][1])),
                bool(c["positive"]),
                None if c["point"] is None else np.asarray(c["point"], np.float64),
                c["view"],
            )
            for c in cs
        ]
    for cd in od.get("corrections", ()):  # absent in older sessions
        obj.corrections.append(
            Correction(
                int(cd["index"]),
                bool(cd["positive"]),
                np.asarray(cd["point"], np.float64),
                float(cd["radius"]),
                np.asarray(arrays[cd["patch"]], np.int64),
                ClickSource.from_dict(cd["source"]),
                tuple(str(v) for v in cd["views"]),
                cd.get("spawned"),
            )
        )
    for vd in od["views"]:
        cv = CentroidView(
            Camera.from_dict(vd["camera"]),
            float(vd["d_cam"]),
            np.asarray(vd["target"], np.float64),
            (float(vd["xy"][0]), float(vd["xy"][1])),
            float(vd["depth"]),
            None if vd["box"] is None else tuple(vd["box"]),
            vd["strategy"],
            float(vd["r_init"]),
            int(vd["neighbours"]),
        )
        v = SessionView(vd["id"], obj.index, int(vd["anchor"]), int(vd["click"]), cv)
        v.status, v.reason = _view_status(vd["status"], path), vd["reason"]
        v.advice = vd.get("advice")  # absent in older sessions
        if vd.get("rejection"):  # absent in older sessions
            v.rejection = Rejection.from_dict(vd["rejection"])
        v.score = float("nan") if vd["score"] is None else float(vd["score"])
        if vd["points"] is not None:
            v.points = np.asarray(vd["points"], np.float64).reshape(-1, 2)
            v.labels = np.asarray(vd["labels"], np.int64)
        if v.status == ViewStatus.FUSED:
            v.mask, v.fusion_id = arrays[vd["mask"]], int(vd["fusion_id"])
            if vd.get("raw_mask"):  # absent in older files: the fused mask stands in
                v.raw_mask = arrays[vd["raw_mask"]]
        obj.views.append(v)
    obj.accept_order = list(od["accept_order"])
    return obj
