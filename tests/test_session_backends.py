"""The session runs over per-representation backends picked from the
scene by a registry; a new representation plugs in by registering a backend, without
touching the loop."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from divas_engine.kinds import SceneKind
from divas_engine.scene import DensityGrid, SurfelScene
from divas_engine.segment import OracleSegmenter
from divas_engine.session import Session, SessionConfig, scene_kind
from divas_engine.session.backends import (
    DensityGridBackend,
    SessionBackend,
    SurfelBackend,
    backend_class_for,
    register_backend,
    registered_backends,
    registry,
)
from divas_engine.synthetic import generate_scene


@pytest.fixture(scope="module")
def ribs():
    return generate_scene("ribs", size=6_000, seed=0, grid_resolution=32)


def test_registry_picks_the_backend_of_each_representation(ribs):
    assert registered_backends() == {SurfelScene: SurfelBackend, DensityGrid: DensityGridBackend}
    assert backend_class_for(ribs.scene) is SurfelBackend
    assert backend_class_for(ribs.grid) is DensityGridBackend
    flat = dataclasses.replace(ribs.scene, kind="3dgs")
    assert flat.kind is SceneKind.GS3D
    # both Gaussian kinds run the surfel path (NOTES "Conventions")
    assert scene_kind(flat) is SceneKind.GS2D and scene_kind(ribs.grid) is SceneKind.NERF
    with pytest.raises(TypeError, match="unsupported scene type object"):
        backend_class_for(object())
    with pytest.raises(ValueError, match="already registered"):
        register_backend(type("Again", (SurfelBackend,), {}))
    with pytest.raises(TypeError, match="not a SessionBackend"):
        register_backend(int)


class _TaggedSurfels(SurfelScene):
    """A 'new representation' for the test: surfels under another type."""


def test_a_registered_backend_drives_the_unchanged_loop(ribs, monkeypatch, tmp_path):
    calls: list[str] = []

    class TaggedBackend(SurfelBackend):
        scene_type = _TaggedSurfels

        def click_depth(self, buffers):
            calls.append("click_depth")
            return super().click_depth(buffers)

        def centroid_view(self, camera, xy, buffers, name, on_camera=None):
            calls.append("centroid_view")
            return super().centroid_view(camera, xy, buffers, name, on_camera)

        def depth_weight(self, mask, buffers, points, labels):
            calls.append("depth_weight")
            return super().depth_weight(mask, buffers, points, labels)

        def selection(self, fused, live):
            calls.append("selection")
            return super().selection(fused, live)

    monkeypatch.setattr(registry, "_BACKENDS", dict(registry._BACKENDS))
    register_backend(TaggedBackend)
    fields = {f.name: getattr(ribs.scene, f.name) for f in dataclasses.fields(SurfelScene)}
    tagged = _TaggedSurfels(**fields)
    cam = ribs.cameras[0]
    xyz = np.asarray(ribs.metadata["clicks"][0]["xyz"])

    def run(scene):
        s = Session.open(
            scene,
            ribs.cameras,
            SessionConfig(render_scale=0.25),
            OracleSegmenter(),
            "cpu",
            anchors=[cam],
            gt_values=ribs.labels,
            render_anchors=False,
        )
        uv, _ = s.anchors[0].camera.project(xyz[None])
        s.accept(s.click(0, uv[0]))
        return s

    plain, s = run(ribs.scene), run(tagged)
    assert isinstance(s.backend, TaggedBackend) and isinstance(plain.backend, SurfelBackend)
    assert {"centroid_view", "depth_weight", "selection"} <= set(calls)
    assert s.selection.any() and np.array_equal(s.selection, plain.selection)
    # the saved session names the backend's kind and replays through the same backend
    s2 = Session.load(s.save(tmp_path / "tagged.json"), tagged, device="cpu")
    assert isinstance(s2.backend, TaggedBackend) and s2.replay_matches
    for x in (plain, s, s2):
        x.close()


def test_backend_interface_is_abstract():
    with pytest.raises(TypeError):
        SessionBackend(None, SessionConfig(), forward_facing=False, device="cpu", renderer=None)
