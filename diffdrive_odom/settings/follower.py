"""The path follower node's parameters and their validation (no rclpy import).

Every own name starts with ``follower.``: the package's nodes read one YAML under
``/**``, and a bare ``k_p`` or ``rate`` would one day mean something else to another
node. The geometry rows are every node's (``geometry_settings.GEOMETRY_PARAMS``) and
``enable_stamped_cmd_vel`` is the cmd_vel node's row (same topic, same type), so the
follower and the cmd_vel node can never disagree about either.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path as FilePath
from typing import Any

from diffdrive_odom.core.errors import require_finite_min
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.motion.path_following import Gains
from diffdrive_odom.core.motion.paths import Path, Point, circle, polyline, route_points
from diffdrive_odom.core.motion.routes import make_route
from diffdrive_odom.core.motion.routes import names as route_names
from diffdrive_odom.settings.errors import ParameterError, as_parameter_error, one_of
from diffdrive_odom.settings.geometry import (
    GEOMETRY_PARAMS,
    LOCKSTEP_PARAM,
    STAMPED_CMD_VEL_PARAM,
    build_geometry,
)
from diffdrive_odom.settings.params import (
    NON_NEGATIVE,
    POSITIVE,
    ParamSpec,
    ParamValue,
    Range,
    coerce_all,
    defaults,
    from_fields,
)

PREFIX = "follower."
NONE, LINE, CIRCLE, POLYLINE, ROUTE = "none", "line", "circle", "polyline", "route"
PATH_TYPES: tuple[str, ...] = (NONE, LINE, CIRCLE, POLYLINE, ROUTE)

# Geometry rows the law uses (wheel names and encoders are the other nodes' business).
_GEOMETRY_USED = ("wheel_radius", "wheel_separation", "left_wheel_radius_multiplier",
                  "right_wheel_radius_multiplier", "wheel_separation_multiplier",
                  "left_wheel_sign", "right_wheel_sign")


def _p(name: str) -> str:
    return PREFIX + name


FOLLOWER_OWN_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec(_p("path_type"), "string", NONE,
              "Path at start: none (wait for one on the path topic), line, circle, "
              "polyline or route."),
    ParamSpec(_p("points"), "double_array", [0.0, 0.0, 2.0, 0.0],
              "line / polyline: x0, y0, x1, y1, ... [m] in the odom frame (line: 2 points)."),
    ParamSpec(_p("waypoints_file"), "string", "",
              "polyline: YAML file with 'points: [[x, y], ...]' [m]; non-empty = used "
              "instead of follower.points."),
    ParamSpec(_p("circle"), "double_array", [0.0, 1.0, 1.0],
              "circle: centre x, centre y, radius [m] (followed forever)."),
    ParamSpec(_p("clockwise"), "bool", False, "circle: travel clockwise."),
    ParamSpec(_p("route"), "string", "square",
              "route: a scripted route's corners (square, square_cw, umbmark_cw, "
              "umbmark_ccw, umbmark) from the origin."),
    ParamSpec(_p("route_size"), "double", 0.0,
              "route: side [m]; 0 = the route's default (1 m square, 4 m UMBmark).",
              range=NON_NEGATIVE),
    ParamSpec(_p("corner_radius"), "double", 0.25,
              "Fillet radius at polyline corners [m], > 0 (shrinks on short legs).",
              range=POSITIVE),
    ParamSpec(_p("desired_speed"), "double", 0.2, "v_des along the path [m/s], > 0.",
              range=POSITIVE),
    ParamSpec(_p("k_p"), "double", 1.0,
              "Path error gain [1/s], > 0: the cross-track error decays as exp(-k_p t).",
              range=POSITIVE),
    ParamSpec(_p("k_i"), "double", 1.0,
              "Speed error integral gain [1/s], >= 0 (0 = no integral feedback).",
              range=NON_NEGATIVE),
    ParamSpec(_p("look_ahead"), "double", 0.1,
              "l [m], > 0: the controlled point P is l ahead of the axle (l = 0 is singular).",
              range=POSITIVE),
    ParamSpec(_p("max_angular_velocity"), "double", 2.0,
              "Largest omega the follower asks for [rad/s], > 0.", range=POSITIVE),
    ParamSpec(_p("min_alignment"), "double", 0.2,
              "Smallest |Gamma . n| the law divides by, in (0, 1] (heading across the path).",
              range=Range(0.0, 1.0, "> 0")),
    ParamSpec(_p("max_speed_correction"), "double", 0.5,
              "Bound of the integral's speed correction, fraction of desired_speed, [0, 1].",
              range=Range(0.0, 1.0)),
)

FOLLOWER_PARAMS: tuple[ParamSpec, ...] = (
    *(s for s in GEOMETRY_PARAMS if s.name in _GEOMETRY_USED),
    STAMPED_CMD_VEL_PARAM,
    *FOLLOWER_OWN_PARAMS,
    LOCKSTEP_PARAM,
)


@dataclass(frozen=True)
class FollowerSettings:
    """All validated settings of the path follower node."""

    geometry: Geometry
    gains: Gains
    enable_stamped_cmd_vel: bool
    path_type: str
    path: Path | None  # None: wait for a path on the topic
    corner_radius: float


def _pairs(name: str, flat: Sequence[float]) -> list[Point]:
    if len(flat) % 2:
        raise ParameterError(name, f"needs x, y pairs, got {len(flat)} numbers")
    return [(flat[i], flat[i + 1]) for i in range(0, len(flat), 2)]


def read_waypoints(path: str) -> list[Point]:
    """Points of a waypoints YAML file: ``points: [[x, y], ...]`` or a bare list."""
    import yaml

    name = _p("waypoints_file")
    try:
        doc: Any = yaml.safe_load(FilePath(path).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as err:
        raise ParameterError(name, f"cannot read {path}: {err}") from None
    items = doc.get("points") if isinstance(doc, dict) else doc
    if not isinstance(items, list) or not all(
            isinstance(p, list) and len(p) == 2
            and all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in p)
            for p in items):
        raise ParameterError(name, f"{path}: expected 'points: [[x, y], ...]' (numbers)")
    return [(float(p[0]), float(p[1])) for p in items]


def _path(v: Mapping[str, Any]) -> Path | None:
    kind = one_of(_p("path_type"), v[_p("path_type")], PATH_TYPES)
    corner = v[_p("corner_radius")]
    if kind == NONE:
        return None
    if kind == CIRCLE:
        values = v[_p("circle")]
        if len(values) != 3:
            raise ParameterError(_p("circle"), f"needs centre x, centre y, radius, "
                                               f"got {len(values)} numbers")
        with as_parameter_error(PREFIX):
            return Path((circle((values[0], values[1]), values[2],
                                clockwise=v[_p("clockwise")]),))
    if kind == ROUTE:
        size = v[_p("route_size")]
        if not (math.isfinite(size) and size >= 0.0):
            raise ParameterError(_p("route_size"), f"must be >= 0 (0 = default), got {size!r}")
        name = v[_p("route")]
        if name not in route_names() or name in ("circle", "figure_eight"):
            raise ParameterError(_p("route"), f"must be a cornered route (square, square_cw, "
                                              f"umbmark_cw, umbmark_ccw, umbmark), got {name!r}")
        with as_parameter_error(rename={"side": _p("route_size")}):
            points = route_points(make_route(name, size or None))
    else:  # LINE, POLYLINE
        file = v[_p("waypoints_file")]
        points = (read_waypoints(file) if kind == POLYLINE and file
                  else _pairs(_p("points"), v[_p("points")]))
        if kind == LINE and len(points) != 2:
            raise ParameterError(_p("points"), f"a line takes 2 points, got {len(points)}")
    with as_parameter_error(PREFIX):
        return polyline(points, corner)


def follower_settings(values: Mapping[str, ParamValue]) -> FollowerSettings:
    """Validate every follower parameter; the first bad one raises ParameterError."""
    v = coerce_all(FOLLOWER_PARAMS, values)
    geometry = build_geometry({**defaults(GEOMETRY_PARAMS), **v})
    gains = from_fields(Gains, v, PREFIX)
    corner = v[_p("corner_radius")]
    require_finite_min(ParameterError, _p("corner_radius"), corner, exclusive=True)
    return FollowerSettings(
        geometry=geometry,
        gains=gains,
        enable_stamped_cmd_vel=v["enable_stamped_cmd_vel"],
        path_type=v[_p("path_type")],
        path=_path(v),
        corner_radius=corner,
    )
