"""Interactive DivAS sessions (paper Sec. 3, the whole loop) and the headless prompts file.

* :class:`Session` (:mod:`.session`) — open / click / prompt / accept / sync / undo /
  reset / finish_object / export / load (replay). 2DGS runs SAM synchronously, NeRF
  asynchronously with group synchronisation (Sec. 3.4), both with overlay propagation
  (Sec. 3.7): the steps that change its :class:`~.state.SessionState` (the one owner of
  anchors, objects, views, labels and selections), over :class:`~.reader.SessionReader`
  (its parts and every read of them); renders are explicit (:mod:`.rendering`).
* :mod:`.backends` — one :class:`~.backends.SessionBackend` per scene representation
  (surfels, density grids), picked from the scene by a registry: everything the loop
  does differently per representation.
* :mod:`.records` — anchors, clicks, corrections, views, previews, overlays, accept and
  correction results, objects (plain data); :mod:`.masks` — prompt sets and mask
  previews; :mod:`.corrections` — every click as a 3D constraint (beyond the paper);
  :mod:`.fusing` — views into and out of the fusion; :mod:`.edits` — manual edits;
  :mod:`.history` — undo / redo; :mod:`.persistence` — save / replay (file layer
  :mod:`.store`); :mod:`.outputs` — the object files; :mod:`.report` — counts and the
  run report.
* :class:`SessionConfig` — the loop's constants plus the sub-configs it hands down.
* :mod:`.prompts` — the NOTES "Headless prompts file" (version 1): parse, check, resolve.
* :func:`write_labelled_ply` — the scene with an extra ``divas_label`` column.
"""

from .config import CorrectionConfig, SessionConfig, config_from_dict, config_to_dict
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
