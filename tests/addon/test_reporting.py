"""The add-on's plain-language messages for a view the segmenter was unsure about
(issue 16): the segmenter's own hint names the click to add, in the add-on's keys."""

from __future__ import annotations

from divas_engine.segment.graph3d.segmenter import NO_SURFACE

HINT = (
    "No clear edge around your click, so the selection may spill over: add a negative "
    "click on what should not be selected"
)


def test_rejection_with_advice_says_which_click_to_add():
    from blender_addon.reporting import rejection_message

    msg = rejection_message("channel-1 score 0.312 < 0.5", 0.312, HINT)
    assert "confidence 0.31" in msg and "negative click (Shift+click)" in msg
    assert msg.endswith("press Enter") and "channel" not in msg
    # without a hint (SAM, the oracle): the generic advice, as before
    plain = rejection_message("channel-1 score 0.312 < 0.5", 0.312)
    assert "confidence 0.31" in plain and "channel" not in plain and "spilled over" in plain


def test_advice_message_uses_the_add_on_words():
    from blender_addon.reporting import advice_message

    assert advice_message(None) == ""
    assert advice_message(HINT).count("(Shift+click)") == 1
    # the engine's "no surface" hint goes through the plain-language table
    assert "nothing solid under that click" in advice_message(NO_SURFACE)
