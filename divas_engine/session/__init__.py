"""Interactive DivAS sessions (paper Sec. 3, the whole loop) and the headless prompts file.

* :class:`Session` (:mod:`.session`) — open / click / prompt / accept / sync / undo / reset /
  finish_object / export / load (replay): the steps that change its
  :class:`~.state.SessionState`, over :class:`~.reader.SessionReader` (every read of it);
  renders are explicit (:mod:`.rendering`).
* :mod:`.backends` — one :class:`~.backends.SessionBackend` per scene representation (surfels,
  density grids), picked from the scene by a registry.
* :mod:`.records` (plain data), :mod:`.masks` (prompt sets, previews), :mod:`.corrections`
  (every click as a 3D constraint), :mod:`.fusing`, :mod:`.edits` (manual edits),
  :mod:`.history` (undo / redo), :mod:`.persistence` / :mod:`.store` (save / replay),
  :mod:`.outputs` (the object files), :mod:`.report` (counts, run report).
* :class:`SessionConfig` — the loop's constants plus the sub-configs it hands down.
* :mod:`.prompts` — the NOTES "Headless prompts file" (version 1): parse, check, resolve.
* :func:`write_labelled_ply` — the scene with an extra ``divas_label`` column.
"""

from .config import (
    CorrectionConfig,
    SessionConfig,
    WideningConfig,
    config_from_dict,
    config_to_dict,
)
from .labels_io import LABEL_PROPERTY, file_label_values, write_labelled_ply
from .prompts import (
    AnchorPrompt,
    Click,
    Prompts,
    ResolvedAnchor,
    find_training_camera,
    load_prompts,
    parse_prompts,
    resolve_anchors,
)
from .records import (
    AcceptResult,
    AnchorClick,
    AnchorView,
    ClickSource,
    Correction,
    CorrectionResult,
    MaskPreview,
    ObjectRecord,
    Overlay,
    SessionView,
)
from .session import Session, anchor_plan, scene_kind
from .timing import Timings, memory_report

__all__ = [
    "Session",
    "SessionConfig",
    "CorrectionConfig",
    "WideningConfig",
    "Correction",
    "CorrectionResult",
    "ClickSource",
    "SessionView",
    "AnchorView",
    "AnchorClick",
    "MaskPreview",
    "AcceptResult",
    "Overlay",
    "ObjectRecord",
    "anchor_plan",
    "scene_kind",
    "config_to_dict",
    "config_from_dict",
    "Prompts",
    "AnchorPrompt",
    "Click",
    "ResolvedAnchor",
    "parse_prompts",
    "load_prompts",
    "resolve_anchors",
    "find_training_camera",
    "write_labelled_ply",
    "file_label_values",
    "LABEL_PROPERTY",
    "Timings",
    "memory_report",
]
