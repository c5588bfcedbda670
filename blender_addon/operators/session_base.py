"""What the session-step operators share: the live session of the context and a poll
that asks for one.

The plain (``EXEC``) step operators — click, add anchor, accept, sync, undo, reset,
finish object — are what the panel's buttons and headless scripts call; the modal
(:mod:`.segment_modal`) runs the same :mod:`..session_actions` functions.
"""

from __future__ import annotations

from .. import session_registry

__all__ = ["live_session", "SessionOperator"]


def live_session(context):
    """``(object, LiveSession)`` of the active object or the scene camera's owner (the
    session is None when there is none)."""
    return session_registry.find(context)


class SessionOperator:
    """Shared poll: a live session for the active object (or the scene camera's owner)."""

    @classmethod
    def poll(cls, context):
        if live_session(context)[1] is None:
            cls.poll_message_set(
                "No DivAS session yet: select the imported splats and press Start DivAS"
            )
            return False
        return True
