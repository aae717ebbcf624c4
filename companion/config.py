"""Typed configuration: dataclasses with defaults, loaded from YAML and validated.

Every key has a default, so no file is needed. A bad file gives one
:class:`ConfigError` whose message names the file and the key; the CLI prints it as one
line and exits 2. The vision sections *are* the stage parameter dataclasses, so a
threshold is defined once, next to the code that uses it.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from companion.vision.corners import CornerParams
from companion.vision.obstacles import ObstacleParams
from companion.vision.vanishing import VPParams

__all__ = [
    "Config",
    "ConfigError",
    "CameraConfig",
    "VisionConfig",
    "HeadingConfig",
    "PolicyConfig",
    "load_config",
    "from_mapping",
    "check_lens",
]


class ConfigError(ValueError):
    """A configuration problem, with a one-line message naming file and key."""


def _range(lo: float | None = None, hi: float | None = None, **kw: Any) -> dict[str, Any]:
    return {"range": (lo, hi), **kw}


@dataclass(frozen=True)
class CameraConfig:
    focal_px: float | None = field(default=None, metadata=_range(1.0, 100000.0))
    distortion: tuple[float, ...] | None = field(
        default=None, metadata=_range(-100.0, 100.0, length=(1, 5)))
    """the lens's distortion as OpenCV's calibration gives it: (k1, k2, p1, p2, k3) or a
    prefix; needs ``focal_px``, to which it is relative. [0]: a pinhole. None: estimated
    on the video's first frames"""
    device: str = "/dev/video0"
    width: int = field(default=640, metadata=_range(16, 8192))
    height: int = field(default=480, metadata=_range(16, 8192))
    fps: float = field(default=30.0, metadata=_range(1.0, 240.0))
    fourcc: str = "MJPG"
    height_m: float | None = field(default=None, metadata=_range(0.05, 100.0))
    """the camera's height above the floor for range in a dry run (in flight: the
    autopilot's altitude); None: no range without an autopilot"""


@dataclass(frozen=True)
class VisionConfig:
    detector: str = field(default="edlines", metadata={"choices": ("edlines", "lsd")})
    min_segment_frac: float = field(default=0.02, metadata=_range(0.001, 0.5))
    max_segments: int = field(default=300, metadata=_range(10, 5000))
    edge_threshold: float = field(default=20.0, metadata=_range(1.0, 255.0))
    validate_segments: bool = False
    min_step_z: float = field(default=6.0, metadata=_range(0.0, 1000.0))
    """a segment that points at none of the room's VPs (a rotated obstacle's edge, or
    noise) is kept only if its grey step across stands this many standard errors above
    the frame's noise (vision/lines.py ``edge_step_z``); 0 keeps every one"""
    refine_segments: bool = False
    """each segment moved onto its edge's gradient peak, sub-pixel (vision/lines.py);
    off: on real photographs it did not help the layout (docs/evaluation.md)"""
    vanishing: VPParams = field(default_factory=VPParams)
    corners: CornerParams = field(default_factory=CornerParams)
    obstacles: ObstacleParams = field(default_factory=ObstacleParams)


@dataclass(frozen=True)
class HeadingConfig:
    depth_px: float | None = field(default=None, metadata=_range(1.0, 100000.0))


@dataclass(frozen=True)
class PolicyConfig:
    max_turn_deg: float = field(default=30.0, metadata=_range(1.0, 180.0))
    deadband_deg: float = field(default=3.0, metadata=_range(0.0, 45.0))
    turn_time_s: float = field(default=1.0, metadata=_range(0.05, 60.0))
    max_yaw_rate_deg_s: float = field(default=30.0, metadata=_range(1.0, 360.0))
    min_avoid_deg: float = field(default=30.0, metadata=_range(0.0, 60.0))
    resume_course: bool = True
    resume_after_s: float = field(default=1.0, metadata=_range(0.0, 60.0))
    resume_max_rate_deg_s: float = field(default=10.0, metadata=_range(0.5, 90.0))
    resume_clearance_m: float = field(default=0.5, metadata=_range(0.0, 5.0))
    """the course does not resume while the predicted resume passes nearer than this to a
    floor contact measured earlier (policy.resume_path_clearance_m); 0: the rule off. A
    contact within half of it of the vehicle is taken as flown over and forgotten, so at
    least twice the vehicle's radius"""
    hidden_depth_m: float = field(default=1.0, metadata=_range(0.0, 10.0))
    """... nor to the floor an obstacle is taken to cover behind its feet, this far along
    each face that leads away from the camera, nor to the foot of a face seen back to a
    corner whose own foot is not measured (vision/ranging.py ``hidden_extent``): one view
    does not show how deep a piece is; 0: the feet alone"""
    resume_in_view: bool = True
    """the course resumes while the obstacle is still in view, once its feet are measured
    and the predicted resume keeps resume_clearance_m from every contact and the floor
    between and behind them (else only once it left the view)"""
    least_turn: bool = True
    """once the obstacle's feet are measured, the heading flown to pass it is the one
    nearest the course, but min_avoid_deg off it at least, whose straight path keeps
    resume_clearance_m from them and the floor between and behind them
    (policy.clearing_heading), where that is nearer the course than the face's own"""
    # Once the pass-off is taken on one side of the course, frames asking for the other
    # side are not acted on until the vehicle is back on the course and past the last
    # obstacle foot measured (policy.keeps_side).
    keep_pass_side: bool = True
    # Range (camera height known): obstacles beyond act_within_m are not turned for; one in
    # the flight path closer than slow_within_m slows the vehicle, to a stop at
    # stop_within_m. 0 turns the rule off.
    act_within_m: float = field(default=6.0, metadata=_range(0.0, 100.0))
    slow_within_m: float = field(default=3.5, metadata=_range(0.0, 100.0))
    stop_within_m: float = field(default=1.5, metadata=_range(0.0, 100.0))
    path_half_width_m: float = field(default=0.5, metadata=_range(0.05, 10.0))
    # In forward flight, a detection the tracker (vision/tracking.py) has not confirmed
    # is turned for at once (fly, the paper), once its floor contact is measured
    # (ranged), or never (wait); steer_by_track steers by the tracked η instead of the
    # frame's, and applies the same rule to every decision (docs/flight.md).
    unconfirmed: str = field(default="fly", metadata={"choices": ("fly", "ranged", "wait")})
    steer_by_track: bool = False


@dataclass(frozen=True)
class MavlinkConfig:
    url: str = "udpin://127.0.0.1:14540"
    connect_timeout_s: float = field(default=10.0, metadata=_range(0.1, 3600.0))
    obstacle_distance_hz: float = field(default=10.0, metadata=_range(0.0, 50.0))
    """OBSTACLE_DISTANCE to PX4's Collision Prevention while connected (0: never)"""
    obstacle_distance_increment_deg: float = field(default=5.0, metadata=_range(1.0, 45.0))


@dataclass(frozen=True)
class OffboardConfig:
    enabled: bool = False
    setpoint_rate_hz: float = field(default=20.0, metadata=_range(2.5, 100.0))
    stale_after_s: float = field(default=0.5, metadata=_range(0.05, 10.0))
    hold_after_s: float = field(default=3.0, metadata=_range(0.1, 60.0))
    confirm_timeout_s: float = field(default=3.0, metadata=_range(0.5, 30.0))
    retry_after_s: float = field(default=5.0, metadata=_range(0.5, 300.0))
    eta_report_hz: float = field(default=4.0, metadata=_range(0.0, 50.0))
    forward_speed_m_s: float = field(default=0.5, metadata=_range(0.0, 5.0))
    forward_accel_m_s2: float = field(default=0.5, metadata=_range(0.05, 10.0))
    turn_slowdown: float = field(default=0.0, metadata=_range(0.0, 1.0))
    sim_arm_and_takeoff: bool = False
    sim_takeoff_altitude_m: float | None = field(default=None, metadata=_range(0.3, 50.0))


@dataclass(frozen=True)
class ServiceConfig:
    decision_log: str | None = None
    decision_log_max_mb: float = field(default=20.0, metadata=_range(0.01, 10000.0))
    decision_log_backups: int = field(default=5, metadata=_range(0, 1000))
    health_every_s: float = field(default=10.0, metadata=_range(0.5, 3600.0))
    max_frame_gap_s: float = field(default=2.0, metadata=_range(0.1, 60.0))


@dataclass(frozen=True)
class Config:
    camera: CameraConfig = field(default_factory=CameraConfig)
    vision: VisionConfig = field(default_factory=VisionConfig)
    heading: HeadingConfig = field(default_factory=HeadingConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    offboard: OffboardConfig = field(default_factory=OffboardConfig)
    service: ServiceConfig = field(default_factory=ServiceConfig)


def load_config(path: str | Path | None) -> Config:
    """The configuration in the YAML file at ``path``, or the defaults for ``None``."""
    if path is None:
        return Config()
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: config file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{p}: is a directory, not a config file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{p}: cannot read config file ({e.__class__.__name__})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{p}: not valid YAML{where}") from None
    if data is None:
        data = {}
    return from_mapping(data, source=str(p))


def from_mapping(data: Any, source: str = "<config>") -> Config:
    """Build and validate a :class:`Config` from nested mappings (as parsed from YAML)."""
    cfg = _build(Config, data, source, "")
    check_lens(cfg.camera, source)
    return cfg


def check_lens(camera: CameraConfig, source: str = "<config>") -> None:
    """Raise :class:`ConfigError` for distortion coefficients without the focal length
    they are relative to (``[0]``, a pinhole, needs none)."""
    if camera.distortion and any(camera.distortion) and not camera.focal_px:
        raise ConfigError(f"{source}: camera.distortion needs camera.focal_px (its "
                          "coefficients are relative to the focal length)")


def _build(cls: type, data: Any, source: str, prefix: str):
    where = prefix.rstrip(".") or "top level"
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: {where} must be a mapping of keys, got {_show(data)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            raise ConfigError(f"{source}: unknown key '{prefix}{key}'")
    kwargs = {}
    for name, value in data.items():
        kwargs[name] = _value(hints[name], fields[name], value, source, f"{prefix}{name}")
    return cls(**kwargs)


def _value(tp: Any, f: dataclasses.Field, value: Any, source: str, key: str):
    optional = False
    if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        optional = len(args) < len(typing.get_args(tp))
        tp = args[0]
    if value is None:
        if optional:
            return None
        raise ConfigError(f"{source}: {key} must not be empty")
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, source, key + ".")
    if typing.get_origin(tp) is tuple:
        lo_n, hi_n = f.metadata.get("length", (0, None))
        if not isinstance(value, list) or len(value) < lo_n or (
                hi_n is not None and len(value) > hi_n):
            raise ConfigError(f"{source}: {key} must be a list of {lo_n} to {hi_n} numbers, "
                              f"got {_show(value)}")
        item = typing.get_args(tp)[0]
        return tuple(_value(item, f, v, source, f"{key}[{i}]") for i, v in enumerate(value))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: {key} must be true or false, got {_show(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: {key} must be an integer, got {_show(value)}")
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{source}: {key} must be a number, got {_show(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{source}: {key} must be a finite number, got {value}")
    elif tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{source}: {key} must be a string, got {_show(value)}")
        choices = f.metadata.get("choices")
        if choices and value not in choices:
            raise ConfigError(f"{source}: {key} must be one of {', '.join(choices)}, got {value!r}")
        return value
    lo, hi = f.metadata.get("range", (0.0, None))
    if lo is None:
        lo = 0.0
    if value < lo or (hi is not None and value > hi):
        bound = f"between {lo:g} and {hi:g}" if hi is not None else f"at least {lo:g}"
        raise ConfigError(f"{source}: {key} must be {bound}, got {value:g}")
    return value


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."
