"""Parameters of the scene-flow chain (:func:`processing.chain.compute_scene_flow`).

One frozen dataclass with the paper's values as defaults (Sec. 5) and the settings this
project added (warm starts, depth gate, d' coherence, optical-depth differential images);
:meth:`ChainParameters.from_mapping` checks a config's ``processing.parameters``.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["FAR_WARM_FLOW_OPTIONS", "WARM_DISPARITY_OPTIONS", "WARM_FLOW_OPTIONS",
           "ChainParameters"]

#: Solver options on a warm start (see ChainParameters), chosen by measurement
#: (docs/performance.md).
WARM_FLOW_OPTIONS: Mapping[str, Any] = {"n_levels": 6, "n_inner": 2, "n_sor": 8}
#: The flow's options on a warm start from a triple two frames back (two workers): the whole
#: pyramid. That start shares no differential image with this triple; on the finest 6 levels
#: its error stayed in the flow and went into d' (simulated site, 2 workers: mean V_Z -0.04
#: and -0.28 m/s against 0.21 true; with the whole pyramid 0.23 and 0.17). One frame back the
#: finest 6 levels are better (the whole pyramid read Table 3 and the robustness matrix worse).
FAR_WARM_FLOW_OPTIONS: Mapping[str, Any] = {"n_inner": 2, "n_sor": 8}
#: Largest block side of ``ChainParameters.binning``, px (4: a 1280x960 camera as 320x240).
MAX_BINNING = 4
#: The disparity's options on a warm start: the finest 6 levels, the finest of them not solved
#: but interpolated from the next (``finest_level``). There a lagged iteration moved d by
#: 0.004 px and d' by 0.0001 px on average (the bench's plume,
#: benchmarks/warm_level_updates.py), and solving it cost a third of the disparity's time.
#: Interpolated, Table 3 and the wide matrix read the same or better, the combined
#: disturbances of the default and held-out matrices 0.4-0.5 point worse (docs/performance.md,
#: "The disparity's finest level on a warm start").
WARM_DISPARITY_OPTIONS: Mapping[str, Any] = {"n_levels": 6, "n_warps": 1, "n_inner": 2,
                                              "n_sor": 8, "finest_level": 1}


@dataclass(frozen=True)
class ChainParameters:
    """Parameters of the chain; defaults are the paper's values (Sec. 5).

    Attributes
    ----------
    alpha, beta : float
        Flow smoothness and gradient-constancy weights (Eq. 5; 0.05, 0.1).
    gamma1, gamma2 : float
        Smoothness weights of d and d' (Eq. 6; 0.05, 0.5).
    nu : float
        Length weight of the segmentation (Eq. 9; 0.5).
    d0 : float
        Minimum disparity in px (Sec. 4.3): the initial disparity for ``disparity_init =
        "d0"``; for ``"sgm"`` the lower end of the SGM search range and the fill value of
        its holes.
    disparity_init : str
        "sgm" (StereoSGBM on the differential images, holes filled with d0) or "d0".
    sgm_num_disparities : int
        Width of the SGM search range [floor(d0), floor(d0) + N) in px (multiple of 16).
    denoise_lambda : float
        Sobolev prior weight in px^2 (0 disables).
    register : bool
        Remove camera jitter by registering consecutive frames on the static background.
    max_jitter_px : float
        Registration estimates larger than this are taken for gas motion (featureless
        background) and not applied; the result counts them in ``rejected_shifts``. The
        shift between two frames is the difference of two independent jitters: with 0.3
        px per axis it exceeds 1 px in about 6 % of the pairs, hence 1.5.
    registration_pause_after : int
        After this many rejected shifts in a row of a camera (a background with no static
        texture of its own: the fit follows the gas), its next shifts are not estimated but
        taken as rejected, except every :data:`processing.chain.state.PROBE_EVERY`-th,
        which is estimated; one applied shift ends the pause. A rejected estimate costs
        1-2 ms at 320x240. 0: estimate every shift.
    gas_temperature_k : float or None
        Gas temperature in K (about the ambient air temperature). With radiometric curves
        in the geometry, the differential images become differential optical depth, free of
        the background's texture
        (:func:`processing.preprocess.differential.differential_image`); None (or no curves)
        keeps plain differences.
    min_contrast_k : float
        Floor of the gas-background contrast for that division, in K.
    depth_gate : bool
        Remove moving image regions whose stereo disparity lies outside the gas band
        [d0, d0 + sgm_num_disparities] before the solvers (:mod:`processing.preprocess.depth_gate`).
    gate_tolerance_px : float
        Margin of the depth gate around the gas band, px: SGBM's error and the gas's own
        depth spread. Something moving just behind the band's far edge is let through by
        as much. SGBM measured a warm object at 8 m at 29.1 +- 0.4 px (half resolution) and
        gas that lay in its band [32, 96] px at no less than 33 px once the columns left of
        d0 (where gas has no partner in the right view) no longer voted; 3 px let the
        object through, the default 1.5 px removes it.
    gate_grow_fraction : float
        The depth gate's object also takes the connected pixels whose raw change reaches
        this share of the object's median change (:func:`processing.preprocess.depth_gate.
        grow_by_amplitude`): edges of the object seen through gas, whose SGBM disparity
        drifts into the band. In [0, 1]; 0 uses the votes alone. The default 0.5 lies above
        the gas's largest change next to an object 10 K warmer than a plant wall (measured:
        the object's edge changes 4-10x as much as the gas does).
    opaque_gate_gas_k : float or None
        Gas temperature in K (about the ambient air's) for the opaque-edge gate
        (:mod:`processing.preprocess.opaque_gate`): the moving edges of a warm object inside
        the gas's depth band, which the depth gate cannot remove, are removed by their
        differential optical depth. Needs the radiometric curves. None (the default) leaves
        it off: on the wide matrix it turned the object's direction into the gas's but left
        the magnitude short (docs/evaluation-sceneflow.md).
    max_motion_px : int
        Largest image motion within a triple, px: how far the gate's masks grow.
    flow_drop_blanked : bool
        The flow (Eq. 5) has no data term on the pixels the depth gate blanked nor where a
        pixel's warped sample lands on them, as the joint solver (Eq. 6) has none; False
        (the default: better on the wide matrix's development part, worse on its hold-out)
        lets their "no change" hold the flow beside them. On the opaque-edge gate's pixels
        the flow never has one.
    temporal_weight : float
        Share a in [0, 1) of the previous triple's d', carried along the flow, in this
        triple's d' (:mod:`processing.stereo.coherence`); 0 uses each triple alone (the paper).
        The default 0.7 (memory ~3 frames) halved the triple-to-triple scatter of V_Z on
        the robustness matrix. While the history holds n < 3 triples the share is at most
        n / (n + 1) (a running mean until the memory is filled).
    diff_scale : float or None
        Normalisation scale of the differential images in radiance (or count) units. None
        tracks it online: the 0.999 quantile of |I_diff| over both cameras, with
        exponential forgetting ``scale_forgetting`` per triple (kept in the state).
    scale_forgetting : float
        Forgetting factor of the tracked scale (0.02 at 30 Hz ~ 1.7 s memory).
    warm_start : bool
        Start the flow and the disparity from the previous triple's results (needs a
        state; only when this triple follows it, :mod:`processing.chain.state`). The SGM or
        d0 initialisation is then used only on a cold start.
    cold_every : int
        With warm starts on, start every ``cold_every``-th triple of an unbroken warm run
        cold anyway, so that a wrong state does not live longer than that many triples
        (:func:`processing.chain.state.warm_start`); 0 never does. The default 30 (1 s at
        30 Hz and stride 1) costs about one cold start per second (+3 % of the chain).
    restart_keeps_flow : bool
        A scheduled restart (``cold_every``) starts the disparity and d' cold but the flow
        warm, from the previous triple's: a cold flow converges slowly where the frame
        carries no data, and a warm object blanked over a plume at the restart left the
        whole plume's flow short for 20 triples, d' taking up the rest
        (docs/evaluation-sceneflow.md, "A longer scene"). False restarts the flow cold too.
        A scene change or an implausible triple always starts all cold.
    max_gas_speed_m_s : float
        A frame whose mean gas speed exceeds this (m/s) is not a measurement: its summary
        is invalid and flagged ``implausible_speed``, and the next triple starts cold. Gas
        dispersing in wind moves at the wind's speed (a few m/s; 30 m/s is a storm the
        appliance does not measure in); faster means a wrong disparity, for example from
        two frames of different moments paired.
    active_region : bool
        On a warm start, solve the flow and the disparities only inside the box around
        the active pixels and the previous gas mask (:mod:`processing.chain.region`); a
        cold start, a scene change and a box above ``region_max_fraction`` solve the whole
        frame. True (the default): the warm solvers 23 % cheaper on the bench's plume
        (boxes of 65 % of the frame), 41 % on the simulated site's; the robustness matrices
        within about a point of the whole frame's, less false gas (docs/performance.md, the
        active region). False solves the whole frame every time.
    region_margin_px : int
        Margin of that box around the active pixels, px.
    region_max_fraction : float
        A box covering more of the frame than this share is solved as the whole frame.
    flow_options, disparity_options, segmentation_options : mapping
        Further keyword arguments of the three solvers (iteration counts, pyramid ...).
    warm_flow_options, warm_disparity_options : mapping
        Overrides of ``flow_options`` / ``disparity_options`` on a warm start: the
        previous fields are already close, so fewer pyramid levels and iterations do.
    far_warm_flow_options : mapping
        Overrides of ``flow_options`` on a warm start from a triple two frames back (two
        workers alternating, ``ChainState.stride`` 2), instead of ``warm_flow_options``.
    binning : int
        Work on the mean of each ``binning`` x ``binning`` block of the corrected,
        rectified frames (:mod:`processing.chain.binning`): a 640x480 camera binned by 2
        costs what a 320x240 one does. The fields come back at the camera's size; the
        settings in px above (d0, the SGM range, the gate's tolerance, the largest motion,
        the region's margin, the largest jitter) stay in camera pixels. 1 (the default)
        works on every pixel.
    """

    alpha: float = 0.05
    beta: float = 0.1
    gamma1: float = 0.05
    gamma2: float = 0.5
    nu: float = 0.5
    d0: float = 0.0
    disparity_init: str = "sgm"
    sgm_num_disparities: int = 64
    denoise_lambda: float = 2.0
    register: bool = True
    max_jitter_px: float = 1.5
    registration_pause_after: int = 8
    gas_temperature_k: float | None = None
    min_contrast_k: float = 1.0
    depth_gate: bool = True
    gate_tolerance_px: float = 1.5
    gate_grow_fraction: float = 0.5
    opaque_gate_gas_k: float | None = None
    max_motion_px: int = 8
    flow_drop_blanked: bool = False
    temporal_weight: float = 0.7
    diff_scale: float | None = None
    scale_forgetting: float = 0.02
    warm_start: bool = True
    cold_every: int = 30
    restart_keeps_flow: bool = True
    max_gas_speed_m_s: float = 30.0
    active_region: bool = True
    region_margin_px: int = 24
    region_max_fraction: float = 0.7
    flow_options: Mapping[str, Any] = field(default_factory=dict)
    disparity_options: Mapping[str, Any] = field(default_factory=dict)
    segmentation_options: Mapping[str, Any] = field(default_factory=dict)
    warm_flow_options: Mapping[str, Any] = field(
        default_factory=lambda: dict(WARM_FLOW_OPTIONS))
    warm_disparity_options: Mapping[str, Any] = field(
        default_factory=lambda: dict(WARM_DISPARITY_OPTIONS))
    far_warm_flow_options: Mapping[str, Any] = field(
        default_factory=lambda: dict(FAR_WARM_FLOW_OPTIONS))
    binning: int = 1

    def __post_init__(self) -> None:
        if self.disparity_init not in ("sgm", "d0"):
            raise ValueError(
                f"disparity_init must be 'sgm' or 'd0', got {self.disparity_init!r}"
            )
        if self.sgm_num_disparities < 16 or self.sgm_num_disparities % 16:
            raise ValueError(
                f"sgm_num_disparities must be a positive multiple of 16, "
                f"got {self.sgm_num_disparities!r}"
            )
        if self.diff_scale is not None and not self.diff_scale > 0:
            raise ValueError(f"diff_scale must be positive or null, got {self.diff_scale!r}")
        if isinstance(self.cold_every, bool) or not isinstance(self.cold_every, int) \
                or self.cold_every < 0:
            raise ValueError(f"cold_every must be an integer >= 0, got {self.cold_every!r}")
        if isinstance(self.region_margin_px, bool) or not isinstance(self.region_margin_px, int) \
                or self.region_margin_px < 0:
            raise ValueError(f"region_margin_px must be an integer >= 0, "
                             f"got {self.region_margin_px!r}")
        for name in ("flow_drop_blanked", "restart_keeps_flow"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if not self.gate_tolerance_px >= 0:
            raise ValueError(f"gate_tolerance_px must be >= 0, got {self.gate_tolerance_px!r}")
        if self.opaque_gate_gas_k is not None and not 150.0 < self.opaque_gate_gas_k < 400.0:
            raise ValueError("opaque_gate_gas_k must be a temperature in K in (150, 400) or "
                             f"null, got {self.opaque_gate_gas_k!r}")
        if not 0 <= self.gate_grow_fraction <= 1:
            raise ValueError(f"gate_grow_fraction must be in [0, 1], "
                             f"got {self.gate_grow_fraction!r}")
        if not self.max_gas_speed_m_s > 0:
            raise ValueError(f"max_gas_speed_m_s must be positive, "
                             f"got {self.max_gas_speed_m_s!r}")
        if not 0 < self.region_max_fraction <= 1:
            raise ValueError(f"region_max_fraction must be in (0, 1], "
                             f"got {self.region_max_fraction!r}")
        if isinstance(self.registration_pause_after, bool) \
                or not isinstance(self.registration_pause_after, int) \
                or self.registration_pause_after < 0:
            raise ValueError(f"registration_pause_after must be an integer >= 0, "
                             f"got {self.registration_pause_after!r}")
        if isinstance(self.binning, bool) or not isinstance(self.binning, int) \
                or not 1 <= self.binning <= MAX_BINNING:
            raise ValueError(f"binning must be an integer from 1 to {MAX_BINNING}, "
                             f"got {self.binning!r}")
        if not 0 < self.scale_forgetting <= 1:
            raise ValueError(f"scale_forgetting must be in (0, 1], got {self.scale_forgetting!r}")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> ChainParameters:
        """Build from a config mapping; an unknown key raises ValueError naming it (with the
        nearest known name for a near miss, e.g. ``alhpa`` -> ``alpha``)."""
        names = sorted(f.name for f in dataclasses.fields(cls))
        unknown = sorted(set(values) - set(names))
        if unknown:
            hints = []
            for key in unknown:
                near = difflib.get_close_matches(str(key), names, n=1)
                hints.append(f"{key!r}" + (f" (did you mean {near[0]!r}?)" if near else ""))
            raise ValueError(
                f"unknown processing parameter(s) {', '.join(hints)}; "
                f"known: {', '.join(names)}"
            )
        return cls(**dict(values))

    def warm_flow_for(self, steps: int) -> Mapping[str, Any]:
        """The flow's warm-start overrides for a start ``steps`` frames back (1 or 2)."""
        return self.warm_flow_options if steps == 1 else self.far_warm_flow_options
