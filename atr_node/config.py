"""Typed, validated settings loaded from TOML.

The schema is the tree of frozen dataclasses below: every section is a dataclass, every key a
typed field with its default. :func:`load_settings` reads a TOML file, rejects unknown keys
and ill-typed values with a :class:`~atr_node.errors.ConfigError` that names the file and the
dotted key, and checks ranges in each section's ``__post_init__``. The defaults describe a
120 kHz SAS like the Edgetech 4400 of the paper (10 cm pixels, 14 m altitude); the file
``config/default.toml`` spells them out and a test keeps the two equal.

Sections may be given partly: missing keys keep their defaults. A file may also set
``include = "other.toml"`` at top level to start from another file (relative to itself).
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from .errors import ConfigError

DETECTOR_NAMES: tuple[str, ...] = ("mf", "lac", "smf", "z")
"""Detector identifiers in the order of SPEC section 2: matched filter, lacunarity,
segmented matched filter, mean (Z) test."""


def _check(cond: bool, key: str, message: str) -> None:
    if not cond:
        raise ConfigError(message, key=key)


@dataclass(frozen=True)
class MissionSettings:
    """The mission metric frame (SPEC section 7)."""

    frame: Literal["utm", "ltp"] = "utm"
    """``utm``: UTM zone of the mission origin (east/north are UTM easting/northing);
    ``ltp``: local tangent plane (azimuthal equidistant) centred on the origin."""
    origin_lat_deg: float | None = None
    """Mission origin; absent: the first navigation fix of the mission."""
    origin_lon_deg: float | None = None

    def __post_init__(self) -> None:
        _check((self.origin_lat_deg is None) == (self.origin_lon_deg is None), "mission.origin_lat_deg",
               "origin_lat_deg and origin_lon_deg are given together or not at all")
        if self.origin_lat_deg is not None:
            _check(-90.0 <= self.origin_lat_deg <= 90.0, "mission.origin_lat_deg", "must be in [-90, 90]")
            _check(-180.0 <= self.origin_lon_deg <= 360.0, "mission.origin_lon_deg", "must be in [-180, 360]")


@dataclass(frozen=True)
class SensorSettings:
    """The sonar, when tiles do not carry a ``sensor`` map (ICD section 1)."""

    frequency_hz: float = 120e3
    bandwidth_hz: float = 15e3
    tx_length_m: float = 0.2
    """Transmit array length L_T; SAS along-track resolution is L_T / 2."""
    rx_length_m: float = 1.2
    """Receive array length L_R."""
    n_rx: int = 24
    sas: bool = True
    altitude_m: float = 14.0
    """Nominal altitude above the seabed (the per-ping altitude from nav wins)."""
    first_return_band_m: float = 0.5
    """Slant metres after the first bottom return (R = altitude) that give no evidence: the
    bright nadir return and its ringing (0.3-0.4 m measured on the real XTF files, whose
    transmit ring-down lasts as long), which the ground-range conversion stretches over the
    first metres next to the nadir. 0 keeps them. The least band: see ``first_return_level``."""
    first_return_level: float = 0.7
    """The band of a slant tile reaches on to where its first return has risen to this fraction
    of the seabed level, measured on the tile's pings (0.6-1.8 m of slant on the Iver2 file,
    whose beam pattern darkens the seabed next to the nadir): a darker seabed there looks like
    a shadow to the detectors. 0 = the fixed band only."""
    first_return_band_max_m: float = 2.5
    """Longest band ``first_return_level`` may give, slant metres."""
    max_range_m: float = 150.0
    dr_m: float = 0.1
    dx_m: float = 0.1
    sound_speed_m_s: float = 1500.0

    def __post_init__(self) -> None:
        for name in ("frequency_hz", "bandwidth_hz", "tx_length_m", "rx_length_m", "altitude_m",
                     "max_range_m", "dr_m", "dx_m", "sound_speed_m_s"):
            _check(getattr(self, name) > 0, f"sensor.{name}", "must be > 0")
        _check(self.n_rx >= 1, "sensor.n_rx", "must be >= 1")
        _check(self.first_return_band_m >= 0, "sensor.first_return_band_m", "must be >= 0")
        _check(0 <= self.first_return_level < 1, "sensor.first_return_level", "must be in [0, 1)")
        _check(self.first_return_band_max_m >= self.first_return_band_m, "sensor.first_return_band_max_m",
               "must be >= sensor.first_return_band_m")


@dataclass(frozen=True)
class TemplateSettings:
    """The generic proud target and its range-adaptive windows (SPEC section 1)."""

    length_m: float = 2.0
    """Along-track length L of the echo and shadow zones."""
    echo_width_m: float = 0.6
    """Across-track width W of the echo zone."""
    height_m: float = 0.5
    """Target height h, for the shadow length S(r) = h r / (H - h)."""
    shadow_min_m: float = 0.5
    shadow_max_m: float = 8.0
    context_factor: float = 3.0
    """SMF normalisation window N: this many times the template in each direction."""

    def __post_init__(self) -> None:
        for name in ("length_m", "echo_width_m", "height_m", "shadow_min_m", "shadow_max_m"):
            _check(getattr(self, name) > 0, f"template.{name}", "must be > 0")
        _check(self.shadow_max_m >= self.shadow_min_m, "template.shadow_max_m", "must be >= shadow_min_m")
        _check(self.context_factor >= 1.0, "template.context_factor", "must be >= 1")


@dataclass(frozen=True)
class ThresholdSettings:
    """Detector thresholds tau_d used when no performance model is loaded."""

    mf: float = 1.0
    lac: float = 1.5
    smf: float = 0.4
    z: float = 2.0


@dataclass(frozen=True)
class DetectorSettings:
    """Detectors and detection extraction (SPEC sections 2-3)."""

    enabled: tuple[str, ...] = DETECTOR_NAMES
    threshold: ThresholdSettings = field(default_factory=ThresholdSettings)
    background_forgetting: float = 0.8
    """Replaced by ``background_memory_m`` (issue 21: forgetting per tile made the background
    depend on tile sizes); a config that sets another value is refused with that message."""
    background_memory_m: float = 115.0
    """e-folding length along track of the background b(j) and median m(j) tracked over a leg:
    each ping forgets ``exp(-dx / memory)`` of the past, whatever the tile sizes (115 m: the
    0.8 per 256-ping tile at 0.1 m spacing it replaces)."""
    min_valid_fraction: float = 0.5
    """A window with fewer valid pixels than this scores NaN (SPEC 2; the SMF's context window)."""
    min_valid_fraction_zones: float = 0.75
    """The echo and shadow zones need this fraction of their pixels valid, or the window scores
    NaN: at a no-data edge (the first-return band next to the nadir, the end of the swath) a
    half-valid echo zone measures the edge, and scored 10-30 times a wreck's gamma on the real
    Iver2 file (``docs/xtf.md``). The larger of this and ``min_valid_fraction`` applies."""
    lacunarity_floor: float = 1e-3
    """mean^2 floor of the lacunarity, as a fraction of the squared background."""
    sigma_floor: float = 1e-3
    """Standard-deviation floor of the mean test, as a fraction of the background."""
    min_extent_m: float = 0.2
    max_extent_m: float = 6.0
    precision: Literal["float64", "float32"] = "float64"
    """Summed-area tables in float64 (exact) or float32 (faster, loses digits)."""
    decimation: int = 1
    """Score every n-th pixel in each direction (speed option; 1 = full resolution)."""
    objects: bool = True
    """Seabed objects (``detectors/objects.py``): one detection per detector for an extended
    object (a wreck), with its extent; bright bands at constant range are background."""
    object_highlight: float = 2.0
    """A highlight is smoothed I_n above this many times the unit's median."""
    object_shadow: float = 0.3
    """A shadow is smoothed I_n below this many times the unit's median."""
    max_object_length_m: float = 60.0
    """A highlight object longer than this is background (no detection)."""
    patch_one_look: bool = False
    """Declutter, off by default: a textured patch (``detectors/objects.py``: bright, at least two
    template lengths, at most ``max_object_length_m``, no shadow at the coarse scale: a rock
    pile, a mound) gives one look per unit, at its strongest place, not one per rock. About half
    the false alarms, but a target in a patch with a stronger rock is lost (docs/detectors.md)."""
    relocate: tuple[str, ...] = ("lac",)
    """Detectors whose detections are placed at the matched filter's peak within their template
    window instead of at their own score's peak (when ``mf`` is enabled): the lacunarity is a
    texture statistic of one window and peaks up to a window's length off the object's
    echo/shadow boundary, which the matched filter marks (docs/detectors.md, "Where a detection
    is placed"). ``[]``: every detector at its own peak, as before."""
    relocate_headroom_db: float = 10.0
    """``relocate`` applies where the seabed's mean intensity lies at least this many dB below
    the recording's full scale (float data: always): where the recording clips, the clipped
    echo places the lacunarity as near as the matched filter does, and moving it cost targets
    on the development seeds' 8-bit renderings (as ``calibration.clip_headroom_db``)."""

    def __post_init__(self) -> None:
        bad = [d for d in self.enabled if d not in DETECTOR_NAMES]
        moved = [d for d in self.relocate if d not in DETECTOR_NAMES or d == "mf"]
        _check(not moved, "detectors.relocate",
               f"unknown detector(s) {moved}; expected some of {[d for d in DETECTOR_NAMES if d != 'mf']} "
               "(the matched filter places the others)")
        _check(len(set(self.relocate)) == len(self.relocate), "detectors.relocate", "lists a detector twice")
        _check(not math.isnan(self.relocate_headroom_db), "detectors.relocate_headroom_db", "must be a number of dB")
        _check(not bad, "detectors.enabled", f"unknown detector(s) {bad}; expected some of {list(DETECTOR_NAMES)}")
        _check(len(set(self.enabled)) == len(self.enabled), "detectors.enabled", "lists a detector twice")
        _check(self.background_forgetting == 0.8, "detectors.background_forgetting",
               "is replaced by detectors.background_memory_m (metres along track, per ping)")
        _check(math.isfinite(self.background_memory_m) and self.background_memory_m > 0,
               "detectors.background_memory_m", "must be finite and > 0")
        _check(0.0 < self.min_valid_fraction <= 1.0, "detectors.min_valid_fraction", "must be in (0, 1]")
        _check(0.0 < self.min_valid_fraction_zones <= 1.0, "detectors.min_valid_fraction_zones",
               "must be in (0, 1]")
        _check(self.lacunarity_floor > 0, "detectors.lacunarity_floor", "must be > 0")
        _check(self.sigma_floor > 0, "detectors.sigma_floor", "must be > 0")
        _check(0 < self.min_extent_m <= self.max_extent_m, "detectors.min_extent_m",
               "must be > 0 and <= max_extent_m")
        _check(self.decimation in (1, 2, 4), "detectors.decimation", "must be 1, 2 or 4")
        _check(self.object_highlight > 1.0, "detectors.object_highlight", "must be > 1")
        _check(0.0 <= self.object_shadow < 1.0, "detectors.object_shadow", "must be in [0, 1)")
        _check(self.max_object_length_m >= self.max_extent_m, "detectors.max_object_length_m",
               "must be >= max_extent_m")


@dataclass(frozen=True)
class SimulationSettings:
    """Target signature simulation and the sonar performance model (SPEC section 4)."""

    subrays: int = 2
    """k: k x k sub-rays per pixel (``engine = "rays"``), or k sub-row strips per pixel row
    (``"strips"``)."""
    engine: Literal["rays", "strips"] = "rays"
    """Signature engine (issue 19): ``"rays"`` samples k x k sub-rays per pixel (the tracer
    the shipped model and the missions were made with); ``"strips"`` integrates each of k
    sub-row planes exactly along range, closer to the fine trace at the same k (figures in
    README's speed table); targets it cannot integrate exactly are traced by rays."""
    seabed: Literal["mud", "silt", "sand", "gravel", "rock"] = "silt"
    temperature_c: float = 14.0
    salinity_psu: float = 38.0
    depth_m: float = 30.0
    ph: float = 8.1
    sea_state: float = 1.0
    source_level_db: float = 210.0
    target_strength_db: float = -30.0
    """Scattering strength of a target's surface, dB re 1 m^2 per m^2 (echo of a facet at
    normal incidence filling a slant-range cell)."""
    multipath_db: float = 15.0
    """Multipath floor of shadows, this many dB below the background."""
    mission_legs: int = 4
    """Synthetic missions (``atr-node simulate``): survey legs of the lawnmower."""
    mission_leg_length_m: float = 200.0
    mission_swath_m: float = 50.0
    """Ground swath per side; legs are spaced by it, so most of the area is seen twice."""
    mission_targets: int = 16
    mission_shapes: tuple[str, ...] = ("cylinder", "cone", "wedge")
    """Built-in shapes, or mesh files (.stl/.obj, relative to the config file)."""
    mission_tile_pings: int = 256
    mission_clutter_per_km2: float = 500.0
    """Rocks and other clutter, fixed in the world (seen at the same place on every leg)."""
    mission_ripples: bool = False
    """Add sand-ripple fields (the "hard" variant turns them on, with dense clutter)."""
    mission_nav_error_m: float = 1.0
    """Horizontal 1-sigma of the per-leg navigation offset (the recorded nav differs from the
    truth by it, plus a drift along the leg of about a third of it)."""
    mission_speed_m_s: float = 2.0
    mission_origin_lat_deg: float = 44.08
    mission_origin_lon_deg: float = 9.85

    def __post_init__(self) -> None:
        _check(self.mission_legs >= 1, "simulation.mission_legs", "must be >= 1")
        _check(self.mission_leg_length_m > 0, "simulation.mission_leg_length_m", "must be > 0")
        _check(self.mission_swath_m > 0, "simulation.mission_swath_m", "must be > 0")
        _check(self.mission_targets >= 0, "simulation.mission_targets", "must be >= 0")
        _check(len(self.mission_shapes) >= 1, "simulation.mission_shapes", "must name at least one shape")
        bad = [s for s in self.mission_shapes if s not in ("cylinder", "cone", "wedge", "sphere", "box")
               and not s.lower().endswith((".stl", ".obj"))]
        _check(not bad, "simulation.mission_shapes",
               f"unknown shape(s) {bad}; expected cylinder, cone, wedge, sphere, box or a .stl/.obj file")
        _check(self.mission_tile_pings >= 16, "simulation.mission_tile_pings", "must be >= 16")
        _check(self.mission_clutter_per_km2 >= 0, "simulation.mission_clutter_per_km2", "must be >= 0")
        _check(self.mission_nav_error_m >= 0, "simulation.mission_nav_error_m", "must be >= 0")
        _check(self.mission_speed_m_s > 0, "simulation.mission_speed_m_s", "must be > 0")
        # the simulator's frame is a local tangent plane (valid at any latitude): polar missions
        # are simulated too, so the node's polar frames can be tested (issue 21)
        _check(-90.0 <= self.mission_origin_lat_deg <= 90.0, "simulation.mission_origin_lat_deg", "must be in [-90, 90]")
        _check(1 <= self.subrays <= 16, "simulation.subrays", "must be in [1, 16]")
        _check(self.engine in ("rays", "strips"), "simulation.engine", "must be 'rays' or 'strips'")
        _check(-2.0 <= self.temperature_c <= 40.0, "simulation.temperature_c", "must be in [-2, 40]")
        _check(0.0 <= self.salinity_psu <= 45.0, "simulation.salinity_psu", "must be in [0, 45]")
        _check(self.depth_m >= 0.0, "simulation.depth_m", "must be >= 0")
        _check(0.0 <= self.sea_state <= 9.0, "simulation.sea_state", "must be in [0, 9]")


def _check_span(span: tuple[float, ...], key: str, lo: float, hi: float) -> None:
    _check(len(span) == 2 and span[0] <= span[1], key, "must be [low, high] with low <= high")
    _check(lo <= span[0] and span[1] <= hi, key, f"must lie within [{lo}, {hi}]")


@dataclass(frozen=True)
class PopulationSettings:
    """The injected calibration targets (SPEC sections 4-5; issue 17 item 5).

    Every random target draws, uniformly in each range and independently: a built-in shape,
    a size factor on all its built-in dimensions, a factor per horizontal axis (length,
    width) and one on its height, roll and pitch within +-``tilt_deg``, a burial as a fraction
    of its (tilted) height and a reflectivity in dB on its echo level. A fraction
    ``nominal_fraction`` of the targets is drawn from the nominal population instead (built-in
    size, proud, level, 0 dB): with ``threshold_on = "nominal"`` Dobeck's threshold is set on
    those, and P(y) and the confidence on all. ``mode = "fixed"`` is the population before
    issue 17: every target nominal (the same draws, hence the same model, as then).
    Only calibration injection uses this; synthetic missions render their own targets.

    The default is ``varied`` since the look-level evidence of SPEC 6.1 and its likelihood-ratio
    score: the targets the ratios are learnt from then include the weak, buried and tilted
    ones that other renderers draw (docs/calibration.md has the figures). Under the paper's
    per-detector form it was ``fixed``: there the misses of four correlated detectors are what
    cancel clutter, and the varied population's lower, more honest Pd weakened them (19 -> 36
    contacts on the river recording).
    """

    mode: Literal["varied", "fixed"] = "varied"
    shapes: tuple[str, ...] = ("cylinder", "cone", "wedge", "sphere")
    size_scale: tuple[float, ...] = (0.5, 1.5)
    """Factor on every built-in dimension."""
    axis_scale: tuple[float, ...] = (0.8, 1.25)
    """Extra factor drawn separately for the length and the width (aspect of the outline)."""
    height_scale: tuple[float, ...] = (0.7, 1.4)
    """Extra factor on the height."""
    tilt_deg: float = 20.0
    """Roll and pitch are uniform in [-tilt_deg, tilt_deg]; the target rests on its lowest point."""
    burial_fraction: tuple[float, ...] = (0.0, 0.5)
    """Part of the target's height below the seabed."""
    reflectivity_db: tuple[float, ...] = (-10.0, 10.0)
    """Echo level relative to the sonar model's (``simulation.target_strength_db``)."""
    nominal_fraction: float = 0.5
    """Share of the targets drawn from the nominal population (``mode = "varied"``). Dobeck's
    tau sits in the tail of their responses, so it needs many: with 0.25 the thresholds came
    out lower and false alarms rose by a third on the simulated missions (docs/calibration.md)."""
    threshold_on: Literal["nominal", "population"] = "nominal"
    """Targets Dobeck's rule reads: the nominal ones (thresholds as before issue 17, Pd of the
    whole population at them) or the whole population (lower thresholds)."""

    def __post_init__(self) -> None:
        p = "calibration.population"
        _check(len(self.shapes) >= 1, f"{p}.shapes", "must name at least one shape")
        bad = [s for s in self.shapes if s not in ("cylinder", "cone", "wedge", "sphere", "box")]
        _check(not bad, f"{p}.shapes", f"unknown shape(s) {bad}; expected cylinder, cone, wedge, sphere or box")
        _check_span(self.size_scale, f"{p}.size_scale", 0.05, 20.0)
        _check_span(self.axis_scale, f"{p}.axis_scale", 0.05, 20.0)
        _check_span(self.height_scale, f"{p}.height_scale", 0.05, 20.0)
        _check(0.0 <= self.tilt_deg <= 80.0, f"{p}.tilt_deg", "must be in [0, 80]")
        _check_span(self.burial_fraction, f"{p}.burial_fraction", 0.0, 0.95)
        _check_span(self.reflectivity_db, f"{p}.reflectivity_db", -40.0, 40.0)
        _check(0.0 <= self.nominal_fraction <= 1.0, f"{p}.nominal_fraction", "must be in [0, 1]")


@dataclass(frozen=True)
class CalibrationSettings:
    """Detector performance estimates (SPEC section 5)."""

    targets_per_image: int = 40
    iterations: int = 50
    prior: Literal["area", "fixed"] = "area"
    """Where P(T) per template-sized cell comes from (SPEC 6.1): ``"area"`` from
    ``target_density_km2`` and the cell's area, ``"fixed"`` = ``prior_target`` (the paper)."""
    target_density_km2: float = 2000.0
    """Expected targets per km^2 for ``prior = "area"`` (docs/calibration.md says why 2000)."""
    prior_target: float = 0.1
    """P(T) per cell for ``prior = "fixed"`` (the paper's 0.1)."""
    look_score: Literal["lr", "fisher"] = "lr"
    """The look score z of SPEC 6.1 (docs/fusion.md): ``"lr"`` sums per-detector log likelihood
    ratios of the injected targets against the background (a weak response counts against),
    ``"fisher"`` sums the background tails ``-ln S_N`` (never below 0)."""
    look_weights: Literal["auto", "fit", "sum"] = "auto"
    """How the look score weighs the detectors' log likelihood ratios (``look_score = "lr"``):
    ``"fit"`` = weights >= 0 fitted on the calibration's injected targets against its clean cells
    (a logistic fit: detectors that read the same pixels the same way share their weight; clipped
    places apart); ``"sum"`` = every detector 1; ``"auto"`` (the default since 2026-11-28) = the
    fit where the calibration's seabed clips (at least 200 of its clean cells within
    ``clip_headroom_db`` of the recording's full scale: an integer recording whose echoes saturate,
    where the highlight detectors read the same cut pixels), else the sum. docs/fusion.md,
    "Fitted detector weights", has the figures it was chosen on."""
    look_pd: float = 0.95
    """A look detects where its score z reaches z_tau, the largest threshold that keeps this share
    of the injected targets (fired and z >= z_tau); weaker looks count as misses (SPEC 6.1,
    docs/fusion.md). 0: every look on which a detector fired detects (models before 2026-11-25)."""
    look_z_min: float = 0.0
    """With ``look_score = "lr"``, a look detects only where its score z (the sum of the
    detectors' log likelihood ratios) is above this too: at ``z <= 0`` its joint responses are
    at least as likely on target-free seabed as on a target, and the look is a miss, not a weak
    detection (docs/fusion.md). ``-inf``: no such floor (models before 2026-11-26)."""
    clip_headroom_db: float = 10.0
    """Seabed whose mean intensity lies within this many dB of the recording's full scale (an
    8-bit file's 255: :attr:`~atr_node.records.tile.Tile.saturation`) clips a target's echo: the
    look score's likelihood ratios there come from the injected targets and clean cells there
    (docs/fusion.md, "Clipped recordings"). 10 dB: a highlight 10 times the seabed's intensity,
    about the injected population's median echo, reaches full scale."""
    pd_target: float = 0.95
    range_bin_m: float = 5.0
    """Width of P(y)'s range bins. 5 m: P(y) falls over the last few metres of the swath,
    where the sonar cuts a target's shadow (docs/calibration.md, "P(y) at the swath's end")."""
    online: bool = True
    online_tiles: int = 8
    """On-line calibration uses this many first tiles of the mission (all of a shorter
    recording). Replays hold these tiles until the model is ready and use it from tile 1;
    a live node uses it from the first tile after it arrived (``docs/calibration.md``)."""
    seed: int = 0
    smoothing: Literal["jeffreys", "laplace"] = "jeffreys"
    """Pseudo-counts of the survival functions and Pd: Jeffreys (1/2) or Laplace (1)."""
    confidence_points: int = 64
    """Points of the tabulated confidence c(gamma; tau) from tau to the largest response."""
    online_iterations: int = 10
    """Injection iterations per tile of the on-line calibration (fewer than off-line)."""
    converge_tau: float = 0.05
    """Stop iterating an image early (issue 19) once, for every detector, its threshold moved
    by at most this fraction of the interquartile range of its target responses in the last
    iteration, and ``converge_pd`` holds too; ``iterations`` / ``online_iterations`` stay the
    cap. 0 = never stop early."""
    converge_pd: float = 0.0
    """... and the 95 % Wilson half-width of each detector's Pd at its threshold, pooled over
    the calibration's images (an image's own half-width divided by the square root of their
    number), is at most this. 0 (the default) = never stop early: on the development mission
    every value that stopped before the cap cost a target and 11-33 false alarms, because the
    thresholds and P(y) settle before the confidence tables do (docs/calibration.md); 0.02
    stops the node's on-line calibration after 3-5 of its 10 iterations."""
    population: PopulationSettings = field(default_factory=PopulationSettings)
    """The injected targets (``[calibration.population]``)."""
    online_switch_tile: int = 0
    """Retired (issue 18): replays now use the on-line model from tile 1, holding the first
    ``online_tiles`` tiles until it is ready. Still accepted so that older files load; a
    value other than 0 is ignored with a warning."""

    def __post_init__(self) -> None:
        _check(self.targets_per_image >= 1, "calibration.targets_per_image", "must be >= 1")
        _check(self.confidence_points >= 2, "calibration.confidence_points", "must be >= 2")
        _check(self.online_iterations >= 1, "calibration.online_iterations", "must be >= 1")
        _check(0.0 <= self.converge_tau < 1.0, "calibration.converge_tau", "must be in [0, 1)")
        _check(0.0 <= self.converge_pd < 0.5, "calibration.converge_pd", "must be in [0, 0.5)")
        if self.online_switch_tile != 0:
            import logging

            logging.getLogger(__name__).warning(
                "calibration.online_switch_tile = %d ignored: the setting is retired; replays now hold the "
                "first calibration.online_tiles tiles until the on-line model is ready and use it from "
                "tile 1 (remove the key)", self.online_switch_tile)
        _check(self.iterations >= 1, "calibration.iterations", "must be >= 1")
        _check(0.0 < self.prior_target < 1.0, "calibration.prior_target", "must be in (0, 1)")
        _check(self.prior in ("area", "fixed"), "calibration.prior", "must be 'area' or 'fixed'")
        _check(self.look_score in ("lr", "fisher"), "calibration.look_score", "must be 'lr' or 'fisher'")
        _check(0.0 <= self.look_pd < 1.0, "calibration.look_pd", "must be in [0, 1)")
        _check(math.isfinite(self.clip_headroom_db), "calibration.clip_headroom_db", "must be a finite number of dB")
        _check(not math.isnan(self.look_z_min) and self.look_z_min < math.inf, "calibration.look_z_min",
               "must be a number below inf (-inf: no floor)")
        _check(0.0 < self.target_density_km2 <= 1e6, "calibration.target_density_km2", "must be in (0, 1e6]")
        _check(0.0 < self.pd_target < 1.0, "calibration.pd_target", "must be in (0, 1)")
        _check(self.range_bin_m > 0, "calibration.range_bin_m", "must be > 0")
        _check(self.online_tiles >= 1, "calibration.online_tiles", "must be >= 1")


@dataclass(frozen=True)
class FusionSettings:
    """Dempster-Shafer fusion and the evidence grid (SPEC sections 6-7)."""

    cell_m: float = 0.5
    chunk_cells: int = 32
    """A chunk is chunk_cells x chunk_cells cells, allocated only where covered (a power of
    two is fastest); smaller chunks waste less at coverage edges (docs/fusion.md)."""
    eps: float = 1e-9
    """Masses are clamped to [0, 1 - eps] so total conflict cannot occur."""
    nav_sigma_m: float = 1.0
    """1-sigma horizontal navigation uncertainty, part of the association gate."""
    gate_sigmas: float = 2.0
    """Association gate radius = gate_sigmas * nav_sigma_m + template length_m / 2."""
    commit_after_obs: int = 6
    """Chunks of an open leg untouched by this many of its later observations (tile cores)
    are committed early, bounding the leg's transient memory; 0 = only when the leg ends."""
    report_bel: float = 0.5
    """A contact is reported where Bel(T) reaches this."""
    withdraw_bel: float = 0.4
    """A reported contact whose Bel(T) falls below this is withdrawn (hysteresis)."""
    diagnostics: bool = False
    """Keep per-detector accumulators per cell as well."""
    evidence: Literal["look", "paper"] = "look"
    """(SPEC 6.1) ``"look"``: one piece of evidence per look (leg pass) and cell from the
    detectors' joint behaviour; ``"paper"``: one per detector, detectors independent."""

    def __post_init__(self) -> None:
        _check(self.evidence in ("look", "paper"), "fusion.evidence", "must be 'look' or 'paper'")
        _check(0.05 <= self.cell_m <= 5.0, "fusion.cell_m", "must be in [0.05, 5] m")
        _check(8 <= self.chunk_cells <= 1024, "fusion.chunk_cells", "must be in [8, 1024]")
        _check(0.0 < self.eps < 1e-2, "fusion.eps", "must be in (0, 0.01)")
        _check(self.nav_sigma_m >= 0, "fusion.nav_sigma_m", "must be >= 0")
        _check(self.gate_sigmas >= 0, "fusion.gate_sigmas", "must be >= 0")
        _check(self.commit_after_obs >= 0, "fusion.commit_after_obs", "must be >= 0")
        _check(0.0 < self.withdraw_bel <= self.report_bel < 1.0, "fusion.report_bel",
               "need 0 < withdraw_bel <= report_bel < 1")


@dataclass(frozen=True)
class LinkSettings:
    """The node's links (ICD sections 1-3); URLs and endpoints, empty = not used."""

    sonar_endpoint: str = "tcp://127.0.0.1:5550"
    sonar_socket: Literal["pull", "sub"] = "pull"
    nmea_url: str = ""
    """Any URL pyserial opens: /dev/ttyS1, socket://host:port, loop://, a pty path."""
    nmea_baudrate: int = 115200
    nmea_reconnect: bool = True
    """Reopen the NMEA port with exponential backoff when it fails or drops, instead of stopping."""
    can_interface: str = ""
    """python-can interface: socketcan aboard, virtual on the bench; empty = no CAN."""
    can_channel: str = "can0"
    can_dbc: str = "atr_node.dbc"
    """DBC file, relative to the config file's folder when not absolute."""
    publish_endpoint: str = "tcp://127.0.0.1:5560"
    snapshot_endpoint: str = "tcp://127.0.0.1:5561"
    """(ICD v1.1) Where the node answers late joiners' ``contacts`` requests (ROUTER); "" = off."""
    curve_secret_key_file: str = ""
    """ZeroMQ CURVE: the node's secret certificate (mode 0600); empty = CURVE off (bench loopback).
    See atr_node.security and docs/reliability.md."""
    curve_authorized_dir: str = ""
    """CURVE: folder of public keys (*.key) allowed on the PUB and bound tile sockets; empty = any holder of the node's public key."""
    sonar_server_key_file: str = ""
    """CURVE: the sonar processor's public key, when the tile socket connects to it."""


@dataclass(frozen=True)
class NodeSettings:
    """The on-vehicle service (ICD sections 3 and 6)."""

    data_dir: str = "/var/lib/atr-node"
    queue_tiles: int = 8
    """Bounded queue between ingest and detection, in tiles: live, the node degrades when the
    units in flight hold this many of the latest tile's units (``queue_tiles`` x the units a
    tile of its length makes, at least one each: a 4096-ping tile makes 16 units of 25.6 m at
    0.1 m), and drops units at twice that."""
    heartbeat_s: float = 1.0
    snapshot_every_tiles: int = 20
    record: bool = True
    """Record every received message to an .atrlog in data_dir."""
    nav_max_gap_s: float = 2.0
    """Tiles whose pings are farther than this from any INS fix are held, not georeferenced."""
    tile_margin_m: float = 0.0
    """Extra margin around tiles beyond half the largest window (0 = just that)."""
    unit_length_m: float = 25.6
    """Along-track length of the units the strips are scored in, counted from each strip's
    first ping whatever the tile cut (SPEC section 0: contacts must not depend on it). Longer:
    less margin overhead (two margins of 3 m per unit by default); shorter: less latency
    (a ping's evidence waits for up to this plus one margin of pings)."""
    first_unit_length_m: float = 51.2
    """Along-track length of a strip's first unit (at least ``unit_length_m``): the background
    b(j) and median m(j) that score it are made of its own pings only, and 25.6 m of seabed is
    too few where one object fills much of it (a wreck then raises its own background). Costs
    latency at the start of each strip only."""
    node_id: str = ""
    """This node's id in evidence exchange (unique among exchanging nodes); "" = the host name."""
    exchange_publish: str = ""
    """ZeroMQ endpoint to bind and publish this node's evidence deltas on; "" = do not publish."""
    exchange_peers: tuple[str, ...] = ()
    """Other nodes' exchange endpoints to subscribe to and ingest evidence deltas from."""
    warm_up_mpx: float = 8.0
    """Live mode: the detection worker scores a synthetic unit of this many megapixels when it
    starts, so the first tiles up to that size find its buffers mapped (first touch of that
    memory cost 0.3-1.6 s on the target VM). The worker then holds those buffers (about
    70 B per pixel: ~0.65 GB at 8 Mpx), as it would after its first tile of that size. In
    both modes the main process maps the evidence grid's memory for an open leg of such units
    while the worker starts (``node/warmup.py: fusion_reserve_chunks``: ~225 MB at 8 Mpx).
    Set it to the sonar's unit size; 0 = a tiny warm-up only, nothing reserved."""
    replay_main_scores: bool = True
    """Replay mode (``--speed max``): rather than wait for the worker (back-pressure, or the
    end of the input), the main process takes back the newest units the worker has not
    started and scores them itself (the same pure function: the same results), so neither
    core idles; off = the main process only waits. Not used live (scoring in the main process
    there made the worst tile latency longer: both sides of a ping then score and fuse in
    series)."""
    live_main_scores: bool = True
    """Live mode: while the worker scores one unit, the next ones wait in the main process,
    which scores them itself whenever it is idle: the second side of a ping no longer waits
    for the first (the worst 8-Mpx tile latency about 0.1 s lower, ``tools/bench/node.py latency``).
    Needs ``warm_up_mpx > 0``: the main process then warms up its own detector memory at start,
    as the worker does (another ~0.65 GB at 8 Mpx). Off = every unit goes to the worker."""
    max_tile_pixels: int = 1 << 23
    """Largest tile (rows x cols, after a slant tile's conversion to ground range) the node takes:
    beyond it the tile is refused, counted under ``tile field shape`` (or the nav merge's ``slant
    range axis too long``), before its pixels are converted. Detection and fusion take about
    225 MiB plus 80 B per pixel of the largest tile (``docs/reliability.md``, memory budget): the
    default 8 Mpx (2^23) peaks near 0.9 GiB, within the node's 2 GiB budget with room for the
    evidence grid; the wire format's own limit is 2^28."""

    def __post_init__(self) -> None:
        _check(self.queue_tiles >= 1, "node.queue_tiles", "must be >= 1")
        _check(0.05 <= self.heartbeat_s <= 1.0, "node.heartbeat_s", "must be in [0.05, 1] s (ICD: at least once a second)")
        _check(self.snapshot_every_tiles >= 1, "node.snapshot_every_tiles", "must be >= 1")
        _check(self.nav_max_gap_s > 0, "node.nav_max_gap_s", "must be > 0")
        _check(math.isfinite(self.unit_length_m) and self.unit_length_m > 0, "node.unit_length_m",
               "must be finite and > 0")
        _check(math.isfinite(self.first_unit_length_m) and self.first_unit_length_m >= self.unit_length_m,
               "node.first_unit_length_m", "must be finite and >= node.unit_length_m")
        _check(0 <= self.warm_up_mpx <= 64, "node.warm_up_mpx", "must be in [0, 64] Mpx")
        _check(isinstance(self.max_tile_pixels, int) and 1 <= self.max_tile_pixels <= 1 << 28,
               "node.max_tile_pixels", "must be an integer in [1, 2^28]")


@dataclass(frozen=True)
class RecordingSettings:
    """Recorded files read by replay, convert, batch and calibrate (XTF, JSF; ICD section 6)."""

    crs: str = ""
    """Coordinate reference system of a file's positions when they are projected metres (XTF
    ``NavUnits`` 0), e.g. ``EPSG:32610``; "" = positions are degrees (a projected file then
    fails at once, naming ``--crs``). The command line's ``--crs`` wins."""
    altitude: Literal["auto", "altimeter", "sonar"] = "auto"
    """Altitude used for slant-to-ground conversion: ``altimeter`` as recorded; ``sonar`` from
    the first bottom return in the image; ``auto`` the recorded one where it is plausible, the
    image's where it is missing, zero or implausible."""
    frequency: str | float = "high"
    """XTF from a dual-frequency sonar: which side-scan channel of a side to read, ``high``
    (the finer resolution), ``low`` or a frequency in kHz (docs/xtf.md). The command line's
    ``--frequency`` wins."""

    def __post_init__(self) -> None:
        _check(self.crs == self.crs.strip(), "recording.crs", "must not start or end with spaces")
        # normalised: "HIGH" -> "high", "455" -> 455.0 (a string is a name to every reader)
        object.__setattr__(self, "frequency", frequency_choice(self.frequency, "recording.frequency"))


def frequency_choice(value: Any, option: str = "--frequency") -> str | float:
    """``high``, ``low`` or a frequency in kHz (a number > 0, as text or number): which
    side-scan channel of a dual-frequency recording to read. Anything else is a
    :class:`~atr_node.errors.ConfigError` naming ``option``."""
    if isinstance(value, str) and value.strip().lower() in ("high", "low"):
        return value.strip().lower()
    try:
        khz = math.nan if isinstance(value, bool) else float(value)
    except (TypeError, ValueError):
        khz = math.nan
    if not (math.isfinite(khz) and khz > 0):
        if option.startswith("--"):
            raise ConfigError(f"{option} {value!r}: expected high, low or a frequency in kHz > 0")
        raise ConfigError(f"must be high, low or a frequency in kHz > 0, got {value!r}", key=option)
    return khz


@dataclass(frozen=True)
class Settings:
    """All settings; the root of the TOML file."""

    mission: MissionSettings = field(default_factory=MissionSettings)
    sensor: SensorSettings = field(default_factory=SensorSettings)
    template: TemplateSettings = field(default_factory=TemplateSettings)
    detectors: DetectorSettings = field(default_factory=DetectorSettings)
    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    calibration: CalibrationSettings = field(default_factory=CalibrationSettings)
    fusion: FusionSettings = field(default_factory=FusionSettings)
    links: LinkSettings = field(default_factory=LinkSettings)
    node: NodeSettings = field(default_factory=NodeSettings)
    recording: RecordingSettings = field(default_factory=RecordingSettings)
    source: str | None = field(default=None, compare=False)
    """The file these settings came from (None: built-in defaults)."""

    def replace(self, **sections: Any) -> "Settings":
        """A copy with some sections replaced, e.g. ``s.replace(fusion=FusionSettings(cell_m=1))``."""
        return dataclasses.replace(self, **sections)


# ----------------------------------------------------------------------------------------
# Loading


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return " or ".join(repr(a) for a in typing.get_args(tp))
    if origin in (types.UnionType, typing.Union):
        return " or ".join(_type_name(a) for a in typing.get_args(tp) if a is not type(None))
    if origin is tuple:
        return f"list of {_type_name(typing.get_args(tp)[0])}"
    return getattr(tp, "__name__", str(tp))


def _convert(value: Any, tp: Any, key: str, path: str) -> Any:
    """Check ``value`` against the annotation ``tp``; return it converted (lists -> tuples)."""
    origin = typing.get_origin(tp)
    if origin in (types.UnionType, typing.Union):
        errors = []
        for arg in typing.get_args(tp):
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, key, path)
            except ConfigError as exc:
                errors.append(exc)
        raise ConfigError(f"expected {_type_name(tp)}, got {type(value).__name__} {value!r}", path=path, key=key)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(f"expected one of {list(typing.get_args(tp))}, got {value!r}", path=path, key=key)
        return value
    if origin is tuple:
        if not isinstance(value, list):
            raise ConfigError(f"expected a list, got {type(value).__name__} {value!r}", path=path, key=key)
        item_tp = typing.get_args(tp)[0]
        return tuple(_convert(v, item_tp, f"{key}[{i}]", path) for i, v in enumerate(value))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"expected a table [{key}], got {type(value).__name__}", path=path, key=key)
        return _build(tp, value, key, path)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"expected true or false, got {type(value).__name__} {value!r}", path=path, key=key)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"expected an integer, got {type(value).__name__} {value!r}", path=path, key=key)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"expected a number, got {type(value).__name__} {value!r}", path=path, key=key)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"expected a string, got {type(value).__name__} {value!r}", path=path, key=key)
        return value
    raise ConfigError(f"unsupported schema type {tp!r}", path=path, key=key)  # pragma: no cover


def _build(cls: type, table: dict[str, Any], prefix: str, path: str) -> Any:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init and f.name != "source"}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{prefix}.{key}" if prefix else key
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(f"unknown key; known keys here: {known}", path=path, key=dotted)
        kwargs[key] = _convert(value, hints[key], dotted, path)
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(str(exc).split(": ", 1)[-1], path=path, key=exc.key) from None


def settings_from_dict(table: dict[str, Any], *, path: str = "<dict>") -> Settings:
    """Build validated :class:`Settings` from a parsed TOML table."""
    table = dict(table)
    table.pop("include", None)
    settings = _build(Settings, table, "", path)
    return dataclasses.replace(settings, source=None if path == "<dict>" else path)


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _read_toml(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    path = path.resolve()
    if path in seen:
        raise ConfigError("include loop", path=str(path), key="include")
    try:
        with open(path, "rb") as fh:
            table = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError("file not found", path=str(path)) from None
    except OSError as exc:  # a folder (include = ""), no permission, ...
        raise ConfigError(f"cannot read: {exc.strerror}", path=str(path)) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML: {exc}", path=str(path)) from None
    except UnicodeDecodeError as exc:  # TOML is UTF-8; tomllib decodes before parsing (found by atheris)
        raise ConfigError(f"not valid TOML: not UTF-8 at byte {exc.start}", path=str(path)) from None
    include = table.get("include")
    if include is not None:
        if not isinstance(include, str):
            raise ConfigError("expected a file name", path=str(path), key="include")
        base = _read_toml(path.parent / include, seen + (path,))
        table = _merge(base, {k: v for k, v in table.items() if k != "include"})
    return table


def load_settings(path: str | os.PathLike[str] | None = None) -> Settings:
    """Load settings from a TOML file; ``None`` gives the built-in defaults.

    Raises
    ------
    ConfigError
        The file is missing or not TOML, or a key is unknown, ill-typed or out of range; the
        message names the file and the dotted key.
    """
    if path is None:
        return Settings()
    p = Path(path)
    return settings_from_dict(_read_toml(p), path=str(p))


def default_config_path() -> Path:
    """``config/default.toml`` of a source checkout (None of it is needed when installed)."""
    return Path(__file__).resolve().parent.parent / "config" / "default.toml"


def resolve_relative(settings: Settings, name: str) -> Path:
    """A file named in the settings, relative to the settings file's folder when not absolute.

    Relative names that do not exist there are looked up in the checkout's ``config/``
    folder, then in the package's ``data`` folder.
    """
    p = Path(name)
    if p.is_absolute():
        return p
    if settings.source:
        cand = Path(settings.source).resolve().parent / p
        if cand.exists():
            return cand
    cand = default_config_path().parent / p
    if cand.exists():
        return cand
    return Path(__file__).resolve().parent / "data" / p
