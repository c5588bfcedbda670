"""The enums keep the strings that session files, reports and the add-on already use."""

import json

from divas_engine.kinds import SceneKind, ViewStatus


def test_enum_members_equal_and_serialise_as_their_strings():
    assert SceneKind.GS2D == "2dgs" and SceneKind("nerf") is SceneKind.NERF
    assert json.dumps({"s": ViewStatus.FUSED, "k": SceneKind.GS3D}) == '{"s": "fused", "k": "3dgs"}'
    assert [v.accepted for v in ViewStatus] == [False, True, True, False]
