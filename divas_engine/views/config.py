"""Constants of anchor selection and centroid views (paper Sec. 3.2, 3.3, App. C).

Every number the view code uses lives here, with its paper symbol.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ViewConfig"]


@dataclass(frozen=True)
class ViewConfig:
    """Anchor-view and centroid-view defaults (paper values unless noted).

    Anchor views (Sec. 3.2, App. C.1–C.2):
        n_fibonacci: N, size of the Fibonacci candidate pool (eq:fib), 12.
        top_k: K, anchors surfaced by the ranking (alg:view_ranking), 5.
        w_diversity, w_cardinal, w_pitch: w_d, w_c, w_p of I = w_d D + w_c C + w_p P
            (0.4, 0.3, 0.3).
        cardinal_eps: ε of C_i = max_a 1 / (‖d_i − a‖ + ε) (not given by the paper; a
            division guard).
        knn_cameras: training cameras angularly nearest to a direction whose mean
            distance is r_knn (eq:gs-radius; NOTES "Anchors"), 5.
        cap_cone_deg: half-angle of the cone whose cameras give r_cap, degrees (45).
        cap_percentile: r_cap = P_cap of the camera distances in that cone (90).
        forward_facing_resultant: a capture is forward-facing when the mean resultant
            length of the cameras' unit optical axes is ≥ this (≈ 25° spread), else 360°.
        plane_max_tilt_deg: the best-fit-plane normal refines the mean camera up (360°
            captures) only when it lies within this angle of the mean up …
        plane_flatness: … and the plane is well defined: smallest / middle singular
            value of the centred camera centres ≤ this.
        fallback_radius_factor: camera-free anchors of a plan built without the scene
            (centre and r_fg only): at this × r_fg from c_scene (2.5).
        fallback_width, fallback_height, fallback_fx: camera-free intrinsics (640×480, 600).

    Scene up without cameras (not in the paper; :mod:`.ground`, :mod:`.up_direction`):
        up: the user's scene up (``--up``); overrides every estimate. None: estimated.
        convention_up: the capture pipeline's convention, used when no ground plane is
            found: (0, −1, 0), COLMAP-trained 3DGS/2DGS in OpenCV coordinates (what
            SuperSplat, PlayCanvas and most trainers keep).
        ground_points: Gaussians (centres within r_fg, opacity-weighted) sampled for the
            ground search (20000, seeded; 8000 left the furry PlayCanvas logo's estimate
            seed-dependent, 1–22°).
        ground_directions: coarse candidate normals, a Fibonacci sphere (1500 ≈ 5°).
        ground_floor_quantile: the support plane of a direction n sits at this quantile
            of the heights p·n — the fraction allowed below it (floaters, 0.005).
        ground_band: half-thickness of the contact band around that plane, × r_fg (0.03;
            1.5 % put the logo's fuzzy bottom 18° off and the guitar stand's 9°, 4 %
            the biker's soles 13°: swept over the 8 shared captures × 8 seeds).
        ground_min_support: a ground's band holds at least this opacity fraction (0.005).
        ground_min_sharpness: … and its band weight drops by at least this fraction when
            the normal tilts 15° (a plane, not a round bottom; 0.25).
        ground_convention_deg: a ground within this angle of ``convention_up`` refines it
            (30°; COLMAP's frame is the first camera's, a few degrees off level).
        ground_axis_deg, ground_min_coverage: a ground elsewhere is taken only when the
            file was visibly re-oriented: its normal within ``ground_axis_deg`` (5°) of a
            world axis and its band covering ≥ ``ground_min_coverage`` (0.6) of the
            content's footprint on it (a floor under everything: a tile, a room).
        ground_snap_deg: a ground normal this close to a world axis becomes that axis
            (10°; :mod:`.up_direction` says why).
        ground_min_elevation_deg, ground_max_elevation_deg: with a ground, candidate
            anchor directions lie between these elevations above the horizon (10°, 60°).

    Framing of camera-free anchors (:mod:`.framing`):
        frame_fill: the robust foreground extent fills this fraction of the frame along
            its tighter image side (0.65; the target band is 50–80 %).
        frame_quantile: the robust extent of a view spans the opacity-weighted
            [q, 1 − q] quantiles of the projected foreground (0.02).
        frame_points: foreground Gaussians sampled for framing (4000, seeded).
        frame_min_depth: perspective guard: the near end of the robust foreground (its
            weighted ``frame_quantile`` of depth) stays at ≥ this × the distance to the
            look-at point (0.5: nothing in the robust extent is magnified more than 2×
            relative to the object's centre).

    Centroid views (Sec. 3.3, App. C.3):
        zoom_forward_facing, zoom_360: λ of alg:centroid_view (NeRF), 0.67 / 0.47.
        min_alpha_click: accumulated opacity at the click below this → no surface (0.5).
        front_share, front_gap: the surface a click lands on is the pixel's median
            depth ``D_med``, unless a nearer one draws at least ``front_share`` of the
            pixel (1/3): then it is the depth ``z`` where ``1 − T`` first reaches that
            share, when the splats within ``front_gap · z`` of it draw the share
            themselves (a surface, not faint haze spread in depth) and it lies more than
            ``front_gap`` × ``D_med`` in front (0.02) — a thin object in front of a
            background (a spoke drawing 0.41 of the pixel before a wall drawing 0.55) is
            what the user clicked. Beyond the paper (surfel
            scenes: :meth:`~divas_engine.session.backends.surfels.SurfelBackend.click_depth_at`).
        p_f: patch fraction of eq:Rphys, 0.25.
        f_fill: target fill fraction of eq:Rinit and central-patch size of eq:occfrac, 0.5.
        alpha_min: α_min of eq:neigh, 0.1.
        min_neighbours: |N| below this → sparse fallback r_init = z p_f, 5.
        lat_percentile: R_lat = P_lat of the perpendicular offsets (eq:Rlat), 90.
        n_probes: K_r probe radii in linspace(r_init, probe_min_frac r_init), 5.
        probe_min_frac: 0.3.
        tau_occ_factor: τ_occ = 0.85 z_near (eq:tauocc).
        tau_occ_fallback: τ_occ = 0.7 r_k when no neighbour projects in front.
        tau_o: τ_O, accept a probe when the occluded fraction O(r_k) < 0.15 (eq:occfrac).
        probe_scale: σ, probe renders at σ × the anchor resolution (not given by the
            paper; 0.25) …
        probe_min_size: … but at least this many pixels on each side (64).
        probe_full_first: test the first radius r_0 on the full-resolution render of its
            camera — the view's own render when r_0 is taken — instead of a low-resolution
            probe (not in the paper; True: an accepted click then costs one render).
        near_fraction: a centroid view's own near clip, as a fraction of its orbit radius
            ``d_cam`` (not in the paper; 0.05). The paper's failure mode of a centroid
            camera placed *inside* a floater (App. C, Strategy 2) has a faint form that
            eq:occfrac cannot see: a floater with α ≈ 0.05 a few centimetres from the
            camera leaves D_med alone but sets D_min (first weight ≥ τ_sig) over half
            the image, and eq:behind-gate then drops every voxel behind those
            see-through pixels. The reference 2DGS/3DGS rasterizers cull primitives at
            camera z ≤ 0.2 scene units — about 5 % of their typical viewing distance;
            this is that rule made scale-free for the views DivAS synthesises. The
            clicked surface sits at ``d_cam``, far behind ``0.05 d_cam``. 0 disables it
            (the renderer's near alone).
    """

    # anchors
    n_fibonacci: int = 12
    top_k: int = 5
    w_diversity: float = 0.4
    w_cardinal: float = 0.3
    w_pitch: float = 0.3
    cardinal_eps: float = 1e-6
    knn_cameras: int = 5
    cap_cone_deg: float = 45.0
    cap_percentile: float = 90.0
    forward_facing_resultant: float = 0.9
    plane_max_tilt_deg: float = 30.0
    plane_flatness: float = 0.5
    fallback_radius_factor: float = 2.5
    fallback_width: int = 640
    fallback_height: int = 480
    fallback_fx: float = 600.0
    up: tuple[float, float, float] | None = None
    convention_up: tuple[float, float, float] = (0.0, -1.0, 0.0)
    ground_points: int = 20000
    ground_directions: int = 1500
    ground_floor_quantile: float = 0.005
    ground_band: float = 0.03
    ground_min_support: float = 0.005
    ground_min_sharpness: float = 0.25
    ground_convention_deg: float = 30.0
    ground_axis_deg: float = 5.0
    ground_min_coverage: float = 0.6
    ground_snap_deg: float = 10.0
    ground_min_elevation_deg: float = 10.0
    ground_max_elevation_deg: float = 60.0
    frame_fill: float = 0.65
    frame_quantile: float = 0.02
    frame_points: int = 4000
    frame_min_depth: float = 0.5
    # centroid views
    zoom_forward_facing: float = 0.67
    zoom_360: float = 0.47
    min_alpha_click: float = 0.5
    front_share: float = 1.0 / 3.0
    front_gap: float = 0.02
    p_f: float = 0.25
    f_fill: float = 0.5
    alpha_min: float = 0.1
    min_neighbours: int = 5
    lat_percentile: float = 90.0
    n_probes: int = 5
    probe_min_frac: float = 0.3
    tau_occ_factor: float = 0.85
    tau_occ_fallback: float = 0.7
    tau_o: float = 0.15
    probe_scale: float = 0.25
    probe_min_size: int = 64
    probe_full_first: bool = True
    near_fraction: float = 0.05

    def __post_init__(self) -> None:
        for name in ("up", "convention_up"):
            v = getattr(self, name)
            if v is None:
                continue
            if len(v) != 3 or not all(math.isfinite(float(x)) for x in v) or not any(v):
                raise ValueError(f"ViewConfig.{name} must be three finite numbers, not all 0")
            object.__setattr__(self, name, tuple(float(x) for x in v))
        if not 0.0 < self.frame_fill < 1.0:
            raise ValueError(f"ViewConfig.frame_fill must be in (0, 1), got {self.frame_fill}")
        if not 0.0 <= self.near_fraction < 1.0:
            raise ValueError(
                f"ViewConfig.near_fraction must be in [0, 1), got {self.near_fraction}"
            )
