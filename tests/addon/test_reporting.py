"""The add-on's plain-language messages for a view the segmenter was unsure about: the
segmenter's own hint names the click to add, in the add-on's keys."""

from __future__ import annotations

from divas_engine.errors import DivasInputError, InputErrorCode
from divas_engine.kinds import RejectReason
from divas_engine.segment.base import Rejection
from divas_engine.segment.graph3d.segmenter import NO_SURFACE

HINT = (
    "No clear edge around your click, so the selection may spill over: add a negative "
    "click on what should not be selected"
)


def test_rejection_with_advice_says_which_click_to_add():
    from blender_addon.reporting import rejection_message

    low = Rejection(RejectReason.LOW_SCORE, 0.312, 0.5, 1)
    msg = rejection_message(low, 0.312, HINT)
    assert "confidence 0.31" in msg and "negative click (Shift+click)" in msg
    assert msg.endswith("press Enter") and "channel" not in msg
    # without a hint (SAM, the oracle): the generic advice
    plain = rejection_message(low, 0.312)
    assert "confidence 0.31" in plain and "channel" not in plain and "spilled over" in plain


def test_a_refused_view_whose_click_holds_says_so():
    from blender_addon.reporting import rejection_message

    low = Rejection(RejectReason.EMPTY_MASK, 0.0, 0.5, 1)
    plain = rejection_message(low)
    held = rejection_message(low, click_holds=True)
    assert "stays selected" in held and "stays selected" not in plain
    assert held.endswith(plain)  # the same advice after it
    assert rejection_message(None, click_holds=True) == ""  # nothing refused: nothing said


def test_advice_message_uses_the_add_on_words():
    from blender_addon.reporting import advice_message

    assert advice_message(None) == ""
    assert advice_message(HINT).count("(Shift+click)") == 1
    # the engine's "no surface" hint goes through the plain-language table
    assert "nothing solid under that click" in advice_message(NO_SURFACE)


def test_every_rejection_and_error_code_has_a_sentence_with_its_numbers():
    """The add-on reads codes and numbers, never the engine's text; the engine's text
    stays what the CLI prints."""
    from blender_addon.reporting import error_message, rejection_message

    low = Rejection(RejectReason.LOW_SCORE, 0.0034, 0.5, 1)
    assert low.message == "channel-1 score 0.003 < 0.5"  # the engine's (CLI) text
    assert "confidence 0.00" in rejection_message(low) and "channel" not in rejection_message(low)
    for reason in RejectReason:
        msg = rejection_message(Rejection(reason, 0.2, 0.5, 1, cause="boom"))
        assert "Enter" in msg and "not added" not in msg, reason
    failed = rejection_message(Rejection(RejectReason.SEGMENTATION_FAILED, cause="boom"))
    assert "(boom)" in failed
    # a view of a session saved before rejections were data: the engine's text, kept
    old = rejection_message(None, reason="channel-1 score 0.200 < 0.5")
    assert "channel-1 score 0.200 < 0.5" in old and "press Enter" in old
    assert rejection_message(None) == ""
    details = {
        InputErrorCode.NO_ANCHOR: {"anchor": 7, "anchors": 3},
        InputErrorCode.FUSION_FULL: {"views": 64},
        InputErrorCode.OTHER_SCENE_SIZE: {"count": 1234},
    }
    for code in InputErrorCode:
        e = DivasInputError(None, "engine text", code=code, details=details.get(code))
        msg = error_message(e)
        assert (msg == "engine text") == (code is InputErrorCode.INPUT), code
    e = DivasInputError(
        None, "x", code=InputErrorCode.NO_ANCHOR, details=details[InputErrorCode.NO_ANCHOR]
    )
    assert "no anchor 7 (this session has 3" in error_message(e)
    # a number the error does not carry: the engine's text rather than a broken sentence
    e = DivasInputError(None, "capacity 2 views: all in use", code=InputErrorCode.FUSION_FULL)
    assert error_message(e) == "capacity 2 views: all in use"
