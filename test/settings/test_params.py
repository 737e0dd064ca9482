"""Parameter validation, frame prefixes, the params YAML reader and config/diffdrive_odom.yaml."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from diffdrive_odom.settings.cmd_vel import CMD_VEL_OWN_PARAMS, CMD_VEL_PARAMS
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.follower import FOLLOWER_OWN_PARAMS, FOLLOWER_PARAMS
from diffdrive_odom.settings.geometry import GEOMETRY_PARAMS, LOCKSTEP_PARAM
from diffdrive_odom.settings.odometry import (
    ODOMETRY_OWN_PARAMS,
    ODOMETRY_PARAMS,
    frame_prefix,
    odometry_settings,
)
from diffdrive_odom.settings.params import ParamSpec
from diffdrive_odom.settings.rcl import load_params_file, parse_override
from diffdrive_odom.settings.registry import unknown_parameters_report
from diffdrive_odom.settings.sim import SIM_PARAMS, sim_settings

from paths import ROOT

CONFIG = ROOT / "config" / "diffdrive_odom.yaml"
VALID: dict[str, Any] = {"wheel_radius": 0.05, "wheel_separation": 0.3}
# The example robot of config/diffdrive_odom.yaml: OptiOdom, r = 0.042 m, b = 0.200 m.
EXAMPLE_ROBOT = {"wheel_radius": 0.042, "wheel_separation": 0.200}
SIX = [0.1] * 6
nan, inf = math.nan, math.inf


# ------------------------------------------------------------------ validation


def test_valid_settings_are_typed_and_complete() -> None:
    settings = odometry_settings({
        "wheel_radius": 1,  # an integer from the command line is a fine radius
        "wheel_separation": 0.3,
        "left_wheel_names": ["fl", "rl"],
        "right_wheel_names": ["fr", "rr"],
        "ticks_per_revolution": 2796.8,
        "encoder_counter_bits": 16.0,  # an integral float is an integer
        "publish_rate": 20,
        "right_wheel_sign": -1,
    })
    assert settings.geometry.wheel_radius == 1.0
    assert isinstance(settings.geometry.wheel_radius, float)
    assert settings.geometry.right_wheel_sign == -1
    assert settings.encoders.left_wheel_names == ("fl", "rl")
    assert settings.encoders.ticks_per_revolution == 2796.8
    assert settings.encoders.counter_bits == 16
    assert settings.publish_rate == 20.0
    assert settings.odom_frame_id == "odom" and settings.base_frame_id == "base_link"
    assert settings.enable_odom_tf is True
    assert len(settings.pose_covariance_diagonal) == 6
    assert all(d > 0 for d in settings.pose_covariance_diagonal[:2])  # non-zero defaults
    assert all(d > 0 for d in settings.twist_covariance_diagonal)


def test_geometry_has_no_usable_default() -> None:
    with pytest.raises(ParameterError) as err:
        odometry_settings({})
    assert err.value.name == "wheel_radius"
    with pytest.raises(ParameterError) as err:
        odometry_settings({"wheel_radius": 0.05})
    assert err.value.name == "wheel_separation"


BAD: list[tuple[str, Any, dict[str, Any]]] = [
    # (parameter named in the error, its bad value, other values it needs)
    ("wheel_radius", 0.0, {}),
    ("wheel_radius", -0.05, {}),
    ("wheel_radius", nan, {}),
    ("wheel_radius", inf, {}),
    ("wheel_radius", "0.05", {}),
    ("wheel_radius", True, {}),
    ("wheel_radius", None, {}),
    ("wheel_separation", 0.0, {}),
    ("wheel_separation", nan, {}),
    ("wheel_separation", -1.0, {}),
    ("wheel_separation", [0.3], {}),
    ("left_wheel_radius_multiplier", 0.0, {}),
    ("right_wheel_radius_multiplier", nan, {}),
    ("wheel_separation_multiplier", -1.0, {}),
    ("left_wheel_sign", 0, {}),
    ("right_wheel_sign", 2, {}),
    ("left_wheel_sign", 1.5, {}),
    ("right_wheel_sign", "-1", {}),
    ("left_wheel_names", [], {}),
    ("right_wheel_names", [], {}),
    ("left_wheel_names", "left_wheel_joint", {}),
    ("left_wheel_names", [3], {}),
    ("left_wheel_names", [""], {}),
    ("right_wheel_names", ["a", "b"], {}),  # unequal to the one left wheel
    ("right_wheel_names", ["left_wheel_joint"], {}),  # same joint on both sides
    ("left_wheel_names", ["a", "a"], {"right_wheel_names": ["b", "c"]}),
    ("right_wheel_names", ["b", "b"], {"left_wheel_names": ["a", "c"]}),
    ("ticks_per_revolution", -1.0, {}),
    ("ticks_per_revolution", nan, {}),
    ("ticks_per_revolution", "2796.8", {}),
    ("encoder_counter_bits", 16, {}),  # a wrapping counter without ticks
    ("encoder_counter_bits", 65, {"ticks_per_revolution": 100.0}),
    ("encoder_counter_bits", -1, {"ticks_per_revolution": 100.0}),
    ("encoder_counter_bits", 16.5, {"ticks_per_revolution": 100.0}),
    ("odom_frame_id", "", {}),
    ("odom_frame_id", "/", {}),
    ("odom_frame_id", 5, {}),
    ("base_frame_id", "", {}),
    ("base_frame_id", "odom", {}),  # child frame equal to the parent frame
    ("tf_frame_prefix_enable", "true", {}),
    ("tf_frame_prefix_enable", 1, {}),
    ("tf_frame_prefix", 3, {}),
    ("enable_odom_tf", "yes", {}),
    ("publish_rate", -1.0, {}),
    ("publish_rate", nan, {}),
    ("publish_rate", inf, {}),
    ("publish_rate", "fast", {}),
    ("pose_covariance_diagonal", [0.1, 0.1, 0.1], {}),
    ("pose_covariance_diagonal", [0.1] * 7, {}),
    ("pose_covariance_diagonal", [nan] + [0.1] * 5, {}),
    ("pose_covariance_diagonal", [-0.1] + [0.1] * 5, {}),
    ("pose_covariance_diagonal", "0.1", {}),
    ("twist_covariance_diagonal", [], {}),
    ("twist_covariance_diagonal", [0.1] * 5 + ["x"], {}),
    ("twist_covariance_diagonal", [inf] + [0.1] * 5, {}),
    ("velocity_rolling_window_size", 0, {}),
    ("velocity_rolling_window_size", -3, {}),
    ("velocity_rolling_window_size", 2.5, {}),
    ("max_wheel_speed", 0.0, {}),
    ("max_wheel_speed", -1.0, {}),
    ("max_wheel_speed", nan, {}),
    ("time_jump_threshold", -1.0, {}),
    ("time_jump_threshold", nan, {}),
    ("time_jump_threshold", inf, {}),
]


@pytest.mark.parametrize(("name", "value", "others"), BAD,
                         ids=[f"{n}={v!r}" for n, v, _ in BAD])
def test_bad_value_is_refused_naming_the_parameter(
    name: str, value: Any, others: dict[str, Any]
) -> None:
    values = {**VALID, **others, name: value}
    with pytest.raises(ParameterError) as err:
        odometry_settings(values)
    assert err.value.name == name
    assert f"'{name}'" in str(err.value)  # the one line the node prints
    assert err.value.reason


@pytest.mark.parametrize(("name", "value", "field"), [
    ("max_wheel_speed", inf, "estimator.max_wheel_speed"),  # no plausibility check
    ("publish_rate", 0.0, "publish_rate"),  # every reading
    ("time_jump_threshold", 0.0, "estimator.time_jump_threshold"),
    ("encoder_counter_bits", 64, "encoders.counter_bits"),
    ("pose_covariance_diagonal", [0.0] * 6, "pose_covariance_diagonal"),
])
def test_boundary_values_are_accepted(name: str, value: Any, field: str) -> None:
    """Accepted and kept as given: the settings carry the boundary value itself."""
    got: Any = odometry_settings({**VALID, "ticks_per_revolution": 1024.0, name: value})
    for part in field.split("."):
        got = getattr(got, part)
    assert (list(got) if isinstance(got, tuple) else got) == value


# -------------------------------------------------------------- frame prefixes


@pytest.mark.parametrize(
    ("enable", "prefix", "namespace", "expected"),
    [
        (True, "", "/", ""),  # no namespace, no prefix
        (True, "", "/robot1", "robot1/"),  # empty prefix = the node's namespace
        (True, "", "/fleet/robot1", "fleet/robot1/"),
        (True, "r2", "/robot1", "r2/"),  # an explicit prefix wins over the namespace
        (True, "r2/", "/", "r2/"),  # a '/' is appended only when missing
        (True, "/r2/", "/", "r2/"),  # tf frame ids never start with '/'
        (False, "r2", "/robot1", ""),
        (False, "", "/robot1", ""),
    ],
)
def test_frame_prefix_rules(enable: bool, prefix: str, namespace: str, expected: str) -> None:
    assert frame_prefix(enable, prefix, namespace) == expected


def test_frames_carry_the_prefix() -> None:
    s = odometry_settings(VALID, namespace="/robot1")
    assert (s.odom_frame_id, s.base_frame_id) == ("robot1/odom", "robot1/base_link")
    s = odometry_settings({**VALID, "odom_frame_id": "/odom"}, namespace="/robot1")
    assert s.odom_frame_id == "robot1/odom"
    s = odometry_settings({**VALID, "tf_frame_prefix": "r2"}, namespace="/robot1")
    assert (s.odom_frame_id, s.base_frame_id) == ("r2/odom", "r2/base_link")
    s = odometry_settings({**VALID, "tf_frame_prefix_enable": False}, namespace="/robot1")
    assert (s.odom_frame_id, s.base_frame_id) == ("odom", "base_link")


# ------------------------------------------------------------ load_params_file


def names(specs: tuple[ParamSpec, ...]) -> list[str]:
    return [s.name for s in specs]


def all_package_params() -> tuple[ParamSpec, ...]:
    """Every node's rows in the shipped file's order, a name shared by nodes once."""
    first: dict[str, ParamSpec] = {}
    for spec in (GEOMETRY_PARAMS + ODOMETRY_OWN_PARAMS + CMD_VEL_OWN_PARAMS + SIM_PARAMS
                 + FOLLOWER_OWN_PARAMS):
        first.setdefault(spec.name, spec)
    return tuple(first.values())


def test_config_file_gives_the_odometry_node_every_parameter() -> None:
    values = load_params_file(CONFIG, "odometry_node")
    assert set(names(ODOMETRY_PARAMS)) <= set(values)
    settings = odometry_settings(values)
    assert settings.geometry.wheel_radius == EXAMPLE_ROBOT["wheel_radius"]
    assert settings.geometry.wheel_separation == EXAMPLE_ROBOT["wheel_separation"]


def test_config_file_gives_the_cmd_vel_node_its_parameters() -> None:
    values = load_params_file(CONFIG, "cmd_vel_node")
    assert set(names(CMD_VEL_PARAMS)) <= set(values)


def test_config_file_gives_the_sim_every_parameter_and_a_valid_rate() -> None:
    """The shipped file starts sim_node too: its /** publish_rate is the odometry node's
    throttle (0 = every reading), the sim's output rate is joint_state_rate (> 0)."""
    values = load_params_file(CONFIG, "sim_node")
    assert set(names(SIM_PARAMS)) <= set(values)
    settings = sim_settings(values)
    assert settings.joint_state_rate == 50.0
    assert settings.config.geometry.wheel_radius == EXAMPLE_ROBOT["wheel_radius"]


@pytest.mark.parametrize(("node", "namespace"), [
    ("odometry_node", "/"), ("odometry_node", "/robot1"), ("cmd_vel_node", "/fleet/robot2"),
    ("diffbot_base_controller", "/"),  # -r __node:=diffbot_base_controller
])
def test_config_file_applies_under_any_name_and_namespace(node: str, namespace: str) -> None:
    values = load_params_file(CONFIG, node, namespace)
    assert set(values) == set(names(all_package_params()))


def test_no_two_nodes_share_a_name_with_different_meanings() -> None:
    """One /** section feeds every node: only the geometry rows may be shared (and the
    follower's enable_stamped_cmd_vel, the cmd_vel node's own row: same topic, same type;
    the odometry node's open loop reads cmd_vel as the cmd_vel node does: its type and
    cmd_vel_timeout)."""
    assert not set(names(ODOMETRY_OWN_PARAMS)) & set(names(CMD_VEL_OWN_PARAMS))
    cmd_rows = {s.name: s for s in CMD_VEL_OWN_PARAMS}
    odometry_cmd = [s for s in ODOMETRY_PARAMS if s.name in cmd_rows]
    assert names(tuple(odometry_cmd)) == ["enable_stamped_cmd_vel", "cmd_vel_timeout"]
    assert all(cmd_rows[s.name] is s for s in odometry_cmd)  # the very same spec
    assert "wheel_command_rate" in names(CMD_VEL_OWN_PARAMS)
    own = set(names(FOLLOWER_OWN_PARAMS))
    assert all(n.startswith("follower.") for n in own)
    assert not own & set(names(ODOMETRY_PARAMS + CMD_VEL_OWN_PARAMS))
    by_name = {s.name: s for s in (*GEOMETRY_PARAMS, *CMD_VEL_OWN_PARAMS, LOCKSTEP_PARAM)}
    for spec in FOLLOWER_PARAMS:  # a shared row is the very same spec
        assert spec.name in own or by_name[spec.name] == spec, spec.name
    # The sim shares the robot's drawing, its joints, the robot's frame and the format of
    # wheel_commands (the topic between cmd_vel_node and the sim): each means the same to
    # both. Its output rate is not the odometry node's publish_rate (0 = every reading).
    others = {s.name: s for s in ODOMETRY_PARAMS + CMD_VEL_OWN_PARAMS + FOLLOWER_OWN_PARAMS}
    shared = {s.name for s in SIM_PARAMS} & set(others)
    assert shared == {"wheel_radius", "wheel_separation", "left_wheel_sign", "right_wheel_sign",
                      "left_wheel_names", "right_wheel_names", "ticks_per_revolution",
                      "encoder_counter_bits", "base_frame_id", "wheel_command_format",
                      "lockstep"}
    for node_params in (SIM_PARAMS, ODOMETRY_PARAMS, CMD_VEL_PARAMS, FOLLOWER_PARAMS):
        assert LOCKSTEP_PARAM in node_params  # the very same row
    for spec in SIM_PARAMS:
        if spec.name in shared:
            assert spec.kind == others[spec.name].kind, spec.name


def test_node_section_overrides_the_wildcard(tmp_path: Path) -> None:
    path = tmp_path / "p.yaml"
    path.write_text(
        "/**:\n  ros__parameters:\n    wheel_radius: 0.1\n    wheel_separation: 0.5\n"
        "/odometry_node:\n  ros__parameters:\n    wheel_radius: 0.2\n"
        "    linear:\n      x:\n        max_velocity: 1.5\n"
        "other_node:\n  ros__parameters:\n    wheel_separation: 9.0\n",
        encoding="utf-8",
    )
    values = load_params_file(path, "odometry_node")
    assert values == {"wheel_radius": 0.2, "wheel_separation": 0.5,
                      "linear.x.max_velocity": 1.5}


def test_empty_and_malformed_files(tmp_path: Path) -> None:
    empty = tmp_path / "empty.yaml"
    empty.write_text("", encoding="utf-8")
    assert load_params_file(empty, "odometry_node") == {}
    listing = tmp_path / "list.yaml"
    listing.write_text("- 1\n- 2\n", encoding="utf-8")
    with pytest.raises(ParameterError) as err:
        load_params_file(listing, "odometry_node")
    assert err.value.name == "--params-file"


# ------------------------------------------------- config/diffdrive_odom.yaml


def sections(text: str) -> dict[str, list[str]]:
    """Parameter lines of each top-level section, in file order."""
    out: dict[str, list[str]] = {}
    current = ""
    for line in text.splitlines():
        if line and not line[0].isspace() and not line.startswith("#"):
            current = line.rstrip(":")
            out[current] = []
        elif line.startswith("    ") and current and not line.strip().startswith("#"):
            out[current].append(line.strip())
    return out


def same(a: Any, b: Any) -> bool:
    """Equality where NaN equals NaN and lists equal tuples."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b) and type(a) is type(b)


PYTHON_TYPE = {"double": float, "integer": int, "bool": bool, "string": str}


def check_section(doc: Mapping[str, Any], lines: list[str], section: str,
                  specs: tuple[ParamSpec, ...], expected: Mapping[str, Any]) -> None:
    params = doc[section]["ros__parameters"]
    assert list(params) == names(specs), section
    assert len(lines) == len(specs)
    for spec, line in zip(specs, lines, strict=True):
        value = params[spec.name]
        want = expected.get(spec.name, spec.default)
        assert same(value, want), (section, spec.name, value, want)
        if spec.kind in PYTHON_TYPE:  # so rcl declares the parameter with the right type
            assert type(value) is PYTHON_TYPE[spec.kind], (spec.name, value)
        elif spec.kind == "double_array":
            assert all(type(v) is float for v in value), (spec.name, value)
        assert line.startswith(f"{spec.name}: ")
        assert f"# {spec.description}" in line, (section, spec.name)
        spec.coerce(value)


def test_config_lists_exactly_the_spec_tables_with_their_defaults() -> None:
    text = CONFIG.read_text(encoding="utf-8")
    doc = yaml.safe_load(text)
    lines = sections(text)
    assert list(doc) == ["/**"]
    assert list(lines) == ["/**"]
    check_section(doc, lines["/**"], "/**", all_package_params(), EXAMPLE_ROBOT)
    geometry = {s.name: s for s in GEOMETRY_PARAMS}
    for spec in CMD_VEL_PARAMS:  # shared rows come from the geometry table: they must agree
        if spec.name in geometry:
            assert same(spec.default, geometry[spec.name].default), spec.name


def test_load_params_file_namespaced_sections_in_rcl_precedence(tmp_path: Path) -> None:
    """rcl: every matching entry applies, in the order the entries first appeared."""
    path = tmp_path / "ns.yaml"
    path.write_text(
        "/**:\n  ros__parameters: {wheel_radius: 0.1, wheel_separation: 0.5}\n"
        "/**/odometry_node:\n  ros__parameters: {wheel_separation: 0.6, publish_rate: 5.0}\n"
        "/robot1/odometry_node:\n  ros__parameters: {publish_rate: 7.0}\n"
        "/robot1/*:\n  ros__parameters: {time_jump_threshold: 2.0}\n"
        "/*:\n  ros__parameters: {max_wheel_speed: 9.0}\n",
        encoding="utf-8",
    )
    plain = load_params_file(path, "odometry_node")
    assert plain == {"wheel_radius": 0.1, "wheel_separation": 0.6, "publish_rate": 5.0,
                     "max_wheel_speed": 9.0}
    spaced = load_params_file(path, "odometry_node", "/robot1")
    assert spaced == {"wheel_radius": 0.1, "wheel_separation": 0.6, "publish_rate": 7.0,
                      "time_jump_threshold": 2.0}


def test_a_wildcard_after_the_node_section_wins(tmp_path: Path) -> None:
    path = tmp_path / "order.yaml"
    path.write_text("odometry_node:\n  ros__parameters: {wheel_radius: 0.2}\n"
                    "/**:\n  ros__parameters: {wheel_radius: 0.1}\n", encoding="utf-8")
    assert load_params_file(path, "odometry_node") == {"wheel_radius": 0.1}


@pytest.mark.parametrize(("text", "value"), [
    ("1", 1), ("017", 15), ("0x1F", 31), ("08", 8.0), ("5e-2", 0.05), ("-.inf", -inf),
    ("y", True), ("Off", False), ('"1"', "1"), ("1_0", "1_0"), ("~", "~"),
    ("[1, 2]", [1, 2]), ("[a, 'b']", ["a", "b"]),
])
def test_values_are_typed_as_rcl_types_them(text: str, value: Any) -> None:
    """Figures from rclpy 7.1.5 itself (-p x:=TEXT, read back from the node)."""
    name, got = parse_override(f"x:={text}")
    assert name == "x" and same(got, value), (text, got)


def test_a_mixed_list_is_refused_as_rcl_does() -> None:
    with pytest.raises(ParameterError):
        parse_override("x:=[1.0, 2]")


def test_unknown_names_get_the_closest_real_one() -> None:
    warning, info = unknown_parameters_report(
        ["wheel_radius", "wheel_seperation_multiplier", "wheel_radious", "publish_rate",
         "wheel_command_rate", "use_sim_time", "qos_overrides./tf.publisher.depth",
         "use_stamped_vel", "position_feedback"])
    assert warning is not None and "\n" not in warning
    assert "wheel_seperation_multiplier (did you mean wheel_separation_multiplier?)" in warning
    assert "wheel_radious (did you mean wheel_radius?)" in warning
    for known in ("publish_rate", "wheel_command_rate", "use_sim_time", "qos_overrides"):
        assert known not in warning
    assert info is not None and "use_stamped_vel" in info and "position_feedback" in info
    assert "open_loop" not in info  # a parameter of odometry_node now (open-loop odometry)
    assert unknown_parameters_report(["wheel_radius", "publish_rate"]) == (None, None)


def test_robot_localizations_names_point_to_ours() -> None:
    """Issue 39 item 5: ``-p publish_tf:=false`` got ``did you mean publish_rate?``;
    publish_tf is robot_localization's name, enable_odom_tf diff_drive_controller's."""
    warning, _ = unknown_parameters_report(["publish_tf", "odom_frame", "base_link_frame"])
    assert warning is not None
    for theirs, ours in (("publish_tf", "enable_odom_tf"), ("odom_frame", "odom_frame_id"),
                         ("base_link_frame", "base_frame_id")):
        assert f"{theirs} (did you mean {ours}? {theirs} is robot_localization's name" \
            in warning, warning
    assert "publish_rate" not in warning
