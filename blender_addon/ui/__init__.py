"""Panels; :data:`CLASSES` is registered in order, unregistered in reverse."""

from __future__ import annotations

from .panel import DIVAS_PT_main

CLASSES = (DIVAS_PT_main,)
