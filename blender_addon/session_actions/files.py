"""Where a session is saved, so that it follows the .blend.

* **Key.** Every object with a session carries a random ``divas_session_key``: unlike its name
  it survives renames and travels through Save As; a duplicate gets its own key on Start.
* **With the .blend.** On ``save_post`` every live session is written to
  ``<blend stem>.divas/<key>.json`` (+ ``.npz``), the sidecar of *that* file, so Save As leaves
  the old sidecar as it was. The anchor and view images are packed into the .blend.
* **Between saves** the engine autosaves after every accept to a recovery file keyed only by
  the key, in the extension's user directory (``bpy.utils.extension_path_user``), so an
  unsaved file's sessions never collide.
* **Reopening.** :func:`saved_session_path` finds the open .blend's sidecar (or one beside a
  renamed .blend), else the recovery file; "Resume DivAS Session" replays it, and with "Resume
  Sessions on Open" every saved session resumes by itself (``load_post``).
* **Relative paths.** With Blender's "Relative Paths" on, the scene-file path is stored
  relative to where the .blend is being saved (``save_pre``).
"""

from __future__ import annotations

import sys
import uuid
from pathlib import Path

import bpy
from bpy.app.handlers import persistent

from .. import bridge, session_registry, source
from ..preferences import ADDON_ID, get_preferences
from ..session_registry import KEY_PROP

__all__ = [
    "SIDECAR_SUFFIX",
    "ensure_key",
    "sidecar_path",
    "user_sessions_dir",
    "recovery_path",
    "saved_session_path",
    "save_sidecars",
    "resume_saved_sessions",
    "on_save_pre",
    "on_save_post",
    "on_load_post",
]

SIDECAR_SUFFIX = ".divas"


def ensure_key(obj) -> str:
    """``obj``'s session key, made when it has none or shares it with another object."""
    key = obj.get(KEY_PROP)
    if key and not any(o.get(KEY_PROP) == key for o in bpy.data.objects if o != obj):
        return str(key)
    key = uuid.uuid4().hex
    obj[KEY_PROP] = key
    return key


def sidecar_path(blend_path: str | Path, key: str) -> Path:
    """``<blend stem>.divas/<key>.json`` beside the .blend."""
    blend = Path(blend_path)
    return blend.parent / f"{blend.stem}{SIDECAR_SUFFIX}" / f"{key}.json"


def user_sessions_dir() -> Path:
    """The add-on's user directory for sessions of unsaved files (created)."""
    try:
        path = bpy.utils.extension_path_user(ADDON_ID, path="sessions", create=True)
    except ValueError:  # registered as a plain add-on (e.g. tests), not as an extension
        path = bpy.utils.user_resource("DATAFILES", path="divas/sessions", create=True)
    return Path(path)


def recovery_path(key: str) -> Path:
    """The autosave of the session keyed ``key``, in :func:`user_sessions_dir`."""
    return user_sessions_dir() / f"{key}.json"


def saved_session_path(obj, *, search: bool = True) -> Path | None:
    """The session file to resume ``obj`` from (module docstring), or None; ``search``:
    also look beside the .blend for a sidecar of another name (the panel skips it)."""
    key = obj.get(KEY_PROP) if obj is not None else None
    if not key:
        return None
    if bpy.data.filepath:
        blend = Path(bpy.path.abspath(bpy.data.filepath))
        own = sidecar_path(blend, key)
        if own.is_file():
            return own
        near = (
            []
            if not search
            else sorted(
                blend.parent.glob(f"*{SIDECAR_SUFFIX}/{key}.json"),
                key=lambda p: p.stat().st_mtime,
                reverse=True,
            )
        )
        if near:
            return near[0]
    rec = recovery_path(key)
    return rec if rec.is_file() else None


def save_sidecars(blend_path: str | Path) -> list[Path]:
    """Write every live session beside ``blend_path`` (never fails the .blend's save:
    a problem goes to the console)."""
    out = []
    for live in session_registry.all_sessions():
        if not live.key:
            continue
        try:
            out.append(live.session.save(sidecar_path(blend_path, live.key)))
        except Exception as e:  # noqa: BLE001 - the .blend is saved; say why the session is not
            print(
                f"DivAS: could not save the session of {live.object_name!r}: {e}", file=sys.stderr
            )
    return out


def _relative_sources(blend_path: str | Path) -> None:
    prefs = bpy.context.preferences.filepaths
    start = str(Path(blend_path).parent)
    for obj in bpy.data.objects:
        raw = obj.get(source.PATH_PROP)
        if obj.type != "POINTCLOUD" or not raw:
            continue
        absolute = bpy.path.abspath(raw)
        if not prefs.use_relative_paths:
            obj[source.PATH_PROP] = absolute
            continue
        try:
            obj[source.PATH_PROP] = bpy.path.relpath(absolute, start=start)
        except ValueError:  # another drive: stays absolute
            obj[source.PATH_PROP] = absolute


@persistent
def on_save_pre(filepath="", *_args) -> None:
    """Scene-file paths relative to where the .blend is being saved; the anchor and view
    images not packed yet packed now (:func:`..bridge.pack_soon`)."""
    if filepath:
        _relative_sources(filepath)
    try:
        bridge.pack_pending()
    except (ReferenceError, RuntimeError) as e:  # a handler must not break the save
        print(f"DivAS: could not pack the view images ({e})", file=sys.stderr)


@persistent
def on_save_post(filepath="", *_args) -> None:
    """The sessions beside the saved .blend; paths relative to the open file again (a
    "Save Copy" went elsewhere)."""
    if not filepath:
        return
    save_sidecars(filepath)
    if bpy.data.filepath:
        _relative_sources(bpy.data.filepath)


def resume_saved_sessions(context) -> list[str]:
    """Resume the saved session of every object that has one and no live session;
    returns the names of the objects resumed."""
    done = []
    for obj in list(bpy.data.objects):
        if (
            source.source_of(obj) is None
            or session_registry.get(obj) is not None
            or saved_session_path(obj) is None
        ):
            continue
        with context.temp_override(active_object=obj, object=obj):
            try:
                ok = bpy.ops.divas.resume_session() == {"FINISHED"}
            except RuntimeError as e:  # the operator's report: keep going with the others
                print(f"DivAS: could not resume {obj.name!r}: {e}", file=sys.stderr)
                ok = False
        if ok:
            done.append(obj.name)
    return done


def _resume_later():
    resume_saved_sessions(bpy.context)
    return None  # a one-shot timer


@persistent
def on_load_post(*_args) -> None:
    """A .blend was opened: resume its sessions when the preference asks for it."""
    prefs = get_preferences()
    if prefs is None or not prefs.resume_on_open:
        return
    if any(o.get(KEY_PROP) for o in bpy.data.objects):
        bpy.app.timers.register(_resume_later, first_interval=0.1)
