"""The session's selection on the object's points: ``divas_selected`` (bool, the current
object's selection) and ``divas_label`` (int, every object's label), written through
:mod:`..bridge` after every change of the selection, so the display material recolours
the splats live."""

from __future__ import annotations

import numpy as np

from divas_engine.errors import DivasInputError
from divas_engine.point_attributes import INDEX, SELECTED, point_values

from .. import bridge
from ..session_registry import LiveSession

__all__ = ["LABEL_ATTRIBUTE", "write_selection"]

#: per-point int32: the label of every finished object plus the current selection.
LABEL_ATTRIBUTE = "divas_label"


def write_selection(obj, live: LiveSession) -> None:
    """``divas_selected`` and ``divas_label`` of ``obj``'s points from the session."""
    s = live.session
    geom = obj.data
    index = bridge.read_attribute(geom, INDEX)
    try:
        selected = point_values(s.scene, index, s.selection).astype(bool)
        labels = point_values(s.scene, index, s.label_set()).astype(np.int32)
    except ValueError:
        raise DivasInputError(
            None,
            f"{obj.name!r} no longer matches the session's scene file (re-imported or "
            "edited outside DivAS?): press Start DivAS on it again",
        ) from None
    bridge.write_attribute(geom, SELECTED, selected)
    bridge.write_attribute(geom, LABEL_ATTRIBUTE, labels)
    geom.update_tag()
