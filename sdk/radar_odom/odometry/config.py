"""`OdometerConfig`: everything a `RadarOdometer` can be told, in one record with a section per stage.

    RadarOdometer(model)                                   # the default: OdometerConfig()
    RadarOdometer(model, config=OdometerConfig.plain())    # plain matching (`radar-odom run --plain`)
    RadarOdometer(model, config=OdometerConfig(prior=None, deskew=DeskewConfig(enabled=True)))

Sections (each a frozen dataclass, checked when made):

- ``time`` (`TimeConfig`): the sensor's period the prior counts in, where stamps stop a stream, and whether
  the match or the stamps say how many periods a step spans.
- ``gaps`` (`GapConfig`): what happens where a step spans dropped sweeps and the match centred where the
  stamps put it cannot read it.
- ``checks`` (`SweepCheckConfig`): when a sweep is too broken to match (`radar_odom.odometry.sweep_checks`).
- ``deskew`` (`DeskewConfig`): motion compensation and yaw centring (both measured options, off).
- ``prior``: the constant-velocity prior fused with each match (`MotionPriorConfig`), or None: no fusion
  and no gate, the prediction only places the search window.

The plain mode (`OdometerConfig.plain`) is the reference every other stage is judged against
(docs/scorecard.md, "Default against plain"): stamps as recorded, consecutive matching, the
constant-velocity prediction only to place the search window, nothing fused, gated or crossed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from ..errors import ConfigError
from .arguments import config_number
from .motion_prior import MotionPriorConfig
from .sweep_checks import MIN_COVERAGE

#: a Navtech CTS350-X turns at 4 Hz (Oxford, RADIATE, Boreas, MulRan, the simulator): the unit the prior
#: counts a step's periods in where the sensor's period is not given
NOMINAL_PERIOD_S = 0.25


def _flag(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ConfigError(f"{name} must be True or False, got {value!r}")
    return bool(value)


@dataclass(frozen=True)
class TimeConfig:
    """The time stage.

    Attributes:
        sweep_period_s: the sensor's period (s) where known; None: `NOMINAL_PERIOD_S` for the prior's unit
            and the median of the stream's one-period intervals for reading stamps.
        max_gap_s: None: every interval up to `radar_odom.odometry.gaps.NEW_SEGMENT_GAP_S` is crossed; a
            number: a longer one is a hard stop (``on_gap``).
        on_gap: beyond ``max_gap_s``: ``"raise"`` (`StreamError`) or ``"reset"`` (a new stream).
        match_decides: True: a step's periods are the ones its match agrees with (a sharp match that agrees
            with one period of motion means no sweep was dropped, whatever the stamps say); False: the
            stamps' count (the plain mode).
    """

    sweep_period_s: float | None = None
    max_gap_s: float | None = None
    on_gap: str = "raise"
    match_decides: bool = True

    def __post_init__(self):
        if self.sweep_period_s is not None:
            object.__setattr__(self, "sweep_period_s", config_number(self.sweep_period_s, "sweep_period_s", low=0.0,
                                                                     open_low=True))
        if self.max_gap_s is not None:
            object.__setattr__(self, "max_gap_s", config_number(self.max_gap_s, "max_gap_s", low=0.0, open_low=True))
        if self.on_gap not in ("raise", "reset"):
            raise ConfigError(f"on_gap must be 'raise' or 'reset', got {self.on_gap!r}")
        object.__setattr__(self, "match_decides", _flag("match_decides", self.match_decides))

    @property
    def prior_period_s(self) -> float:
        """The period (s) one step of the stream counts as for the motion prior."""
        return NOMINAL_PERIOD_S if self.sweep_period_s is None else self.sweep_period_s


@dataclass(frozen=True)
class GapConfig:
    """A step across dropped sweeps whose match, centred where the prediction puts it, read nothing.

    Attributes:
        cross: match it from several window centres around the prediction and take what two sharp readings
            agree on (`radar_odom.odometry.gaps.crossing_readings`); False: the centred match or the prediction.
        max_yaw_accel_rps2: a crossing whose mean yaw rate differs from every yaw rate of the last second by
            more than this × half the gap is a turn the car could not have made: refused.
    """

    cross: bool = True
    max_yaw_accel_rps2: float = math.radians(40.0)

    def __post_init__(self):
        object.__setattr__(self, "cross", _flag("gaps.cross", self.cross))
        object.__setattr__(self, "max_yaw_accel_rps2", config_number(self.max_yaw_accel_rps2, "max_yaw_accel_rps2",
                                                                     low=0.0, open_low=True))


@dataclass(frozen=True)
class SweepCheckConfig:
    """When a sweep is degenerate (`radar_odom.odometry.sweep_checks.sweep_problem`)."""

    min_valid_fraction: float = 0.5
    min_coverage: float = MIN_COVERAGE

    def __post_init__(self):
        for name in ("min_valid_fraction", "min_coverage"):
            object.__setattr__(self, name, config_number(getattr(self, name), name, low=0.0, high=1.0))


@dataclass(frozen=True)
class DeskewConfig:
    """Motion compensation (``enabled``, `radar_odom.odometry.deskew_stage`) and yaw centring
    (``centre_yaw``, `radar_odom.odometry.centring`): measured options, off by default (docs/deskew.md,
    docs/yaw-precision.md). Cartesian stream or pair models only."""

    enabled: bool = False
    centre_yaw: bool = False

    def __post_init__(self):
        object.__setattr__(self, "enabled", _flag("deskew", self.enabled))
        object.__setattr__(self, "centre_yaw", _flag("centre_yaw", self.centre_yaw))


@dataclass(frozen=True)
class OdometerConfig:
    """Every setting of a `RadarOdometer`, a section per stage (see the module docstring)."""

    time: TimeConfig = field(default_factory=TimeConfig)
    gaps: GapConfig = field(default_factory=GapConfig)
    checks: SweepCheckConfig = field(default_factory=SweepCheckConfig)
    deskew: DeskewConfig = field(default_factory=DeskewConfig)
    prior: MotionPriorConfig | None = field(default_factory=MotionPriorConfig)

    def __post_init__(self):
        for name, kind in (("time", TimeConfig), ("gaps", GapConfig), ("checks", SweepCheckConfig),
                           ("deskew", DeskewConfig)):
            if not isinstance(getattr(self, name), kind):
                raise ConfigError(f"OdometerConfig.{name} must be a {kind.__name__}, got {getattr(self, name)!r}")
        if self.prior is not None and not isinstance(self.prior, MotionPriorConfig):
            raise ConfigError(f"OdometerConfig.prior must be a MotionPriorConfig or None, got {self.prior!r}")

    @classmethod
    def plain(cls, **time) -> OdometerConfig:
        """Plain matching: stamps as recorded (their count of periods), consecutive matches, the
        constant-velocity prediction only to place the search window; nothing fused, gated or crossed.
        ``time``: `TimeConfig` fields (e.g. ``sweep_period_s``)."""
        return cls(time=TimeConfig(match_decides=False, **time), gaps=GapConfig(cross=False),
                   prior=None)

    @property
    def is_plain(self) -> bool:
        return self.prior is None and not self.gaps.cross and not self.time.match_decides

    def describe(self) -> str:
        """One line for logs and run summaries."""
        if self.is_plain:
            return "plain matching"
        parts = ["motion prior" if self.prior is not None else "no motion prior",
                 "periods from the match" if self.time.match_decides else "periods from the stamps",
                 "gap crossing" if self.gaps.cross else "no gap crossing"]
        parts += [name for name, on in (("de-skew", self.deskew.enabled), ("yaw centring", self.deskew.centre_yaw))
                  if on]
        return ", ".join(parts)


# the keyword arguments RadarOdometer took before OdometerConfig, and where each lives now
LEGACY_KEYWORDS = {
    "max_gap_s": ("time", "max_gap_s"), "on_gap": ("time", "on_gap"), "sweep_period_s": ("time", "sweep_period_s"),
    "min_valid_fraction": ("checks", "min_valid_fraction"), "min_coverage": ("checks", "min_coverage"),
    "deskew": ("deskew", "enabled"), "centre_yaw": ("deskew", "centre_yaw"),
}


# keywords RadarOdometer took before issue 50 whose stage was removed, and what replaces each
REMOVED_KEYWORDS = {
    "time_base": "the match decides how many periods a step spans; the reader's time base is not passed any more "
                 "(drop the argument)",
    "deskew_gaps": "the gap crossing's de-skew won no row of its ablation (docs/scorecard.md); drop the argument",
}


def config_from(config: OdometerConfig | str | None = None, *, motion_prior=None, **keywords) -> OdometerConfig:
    """The `OdometerConfig` of ``config`` (None: the default; ``"plain"``; ``"default"``) with the keyword
    arguments `RadarOdometer` also takes (``max_gap_s=``, ``deskew=``, ``motion_prior=`` …) applied on top;
    a None keyword leaves the config's value. `ConfigError` for a name it does not know."""
    if config is None or config == "default":
        config = OdometerConfig()
    elif config == "plain":
        config = OdometerConfig.plain()
    elif not isinstance(config, OdometerConfig):
        raise ConfigError(f"config must be an OdometerConfig, 'default' or 'plain', got {config!r}")
    removed = sorted(set(keywords) & set(REMOVED_KEYWORDS))
    if removed:
        raise ConfigError("; ".join(f"{name} was removed: {REMOVED_KEYWORDS[name]}" for name in removed))
    unknown = sorted(set(keywords) - set(LEGACY_KEYWORDS))
    if unknown:
        raise ConfigError(f"unknown odometer option(s) {', '.join(unknown)}; known: "
                          f"{', '.join(sorted(LEGACY_KEYWORDS) + ['motion_prior'])}")
    sections = {f.name: getattr(config, f.name) for f in fields(config)}
    for name, value in keywords.items():
        if value is None:
            continue
        section, attr = LEGACY_KEYWORDS[name]
        sections[section] = replace(sections[section], **{attr: value})
    if motion_prior is not None:
        if isinstance(motion_prior, MotionPriorConfig):
            sections["prior"] = motion_prior
        elif isinstance(motion_prior, (bool, np.bool_)):
            sections["prior"] = (sections["prior"] or MotionPriorConfig()) if motion_prior else None
        else:
            raise TypeError(f"motion_prior must be True, False or a MotionPriorConfig, got {motion_prior!r}")
    return OdometerConfig(**sections)
