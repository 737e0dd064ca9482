"""Parameters as ROS users know them from generate_parameter_library.

Every parameter is declared with its description, its type fixed, its range where one is
true (``ros2 param describe`` shows it) and read-only where a runtime change is not
supported; an integer given for a double is that double; a node's own dump loads back;
a runtime typo names the closest real parameter. The node tests build the real node
classes in a private Context on the shipped config (no process); the command line
itself is test_ros2_cli's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml
from rcl_interfaces.msg import ParameterType
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_dict_from_yaml_file

from diffdrive_odom.ros.cmd_vel_node import CmdVelNode
from diffdrive_odom.ros.odometry_lifecycle_node import OdometryLifecycleNode
from diffdrive_odom.ros.odometry_node import OdometryNode
from diffdrive_odom.ros.path_follower_node import PathFollowerNode
from diffdrive_odom.ros.sim_node import SimNode
from diffdrive_odom.settings.cmd_vel import CMD_VEL_PARAMS, cmd_vel_settings
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.follower import FOLLOWER_PARAMS, follower_settings
from diffdrive_odom.settings.odometry import ODOMETRY_PARAMS, odometry_settings
from diffdrive_odom.settings.params import (
    INT64_MAX,
    ParamSpec,
    as_declared_type,
)
from diffdrive_odom.settings.sim import SIM_PARAMS, sim_settings

from rosutil import ROOT, built

CONFIG = ROOT / "config" / "diffdrive_odom.yaml"
VALID = {"wheel_radius": 0.05, "wheel_separation": 0.3}

# Each node's table, the validation it runs, and values that make the rest valid.
TABLES: dict[str, tuple[tuple[ParamSpec, ...], Callable[[Mapping[str, Any]], Any],
                        dict[str, Any]]] = {
    "odometry": (ODOMETRY_PARAMS, odometry_settings, VALID),
    "cmd_vel": (CMD_VEL_PARAMS, cmd_vel_settings, VALID),
    "sim": (SIM_PARAMS, sim_settings, {}),
    # route: so that follower.route_size is read (a value no path uses is not checked)
    "follower": (FOLLOWER_PARAMS, follower_settings, {**VALID, "follower.path_type": "route"}),
}
NODES: dict[str, tuple[type[Node], tuple[ParamSpec, ...]]] = {
    "odometry_node": (OdometryNode, ODOMETRY_PARAMS),
    "odometry_lifecycle_node": (OdometryLifecycleNode, ODOMETRY_PARAMS),
    "cmd_vel_node": (CmdVelNode, CMD_VEL_PARAMS),
    "sim_node": (SimNode, SIM_PARAMS),
    "path_follower_node": (PathFollowerNode, FOLLOWER_PARAMS),
}
TYPE = {"double": ParameterType.PARAMETER_DOUBLE, "integer": ParameterType.PARAMETER_INTEGER,
        "bool": ParameterType.PARAMETER_BOOL, "string": ParameterType.PARAMETER_STRING,
        "double_array": ParameterType.PARAMETER_DOUBLE_ARRAY,
        "string_array": ParameterType.PARAMETER_STRING_ARRAY}


# --- the ranges are true: every value a range excludes, the validation refuses too ----


def _outside(spec: ParamSpec) -> list[float]:
    """Values outside the spec's closed range (and off its step), and its open bounds."""
    r = spec.range
    assert r is not None
    if spec.kind == "integer":
        ints = [int(r.low) - 1] + ([int(r.high) + 1] if r.high < INT64_MAX else [])
        return [*ints, *([int(r.low) + 1] if r.step > 1 else [])]
    out = [r.low - 1.0, math.nextafter(r.low, -math.inf), math.nan]
    out += [math.nextafter(r.high, math.inf)] if math.isfinite(r.high) else []
    if r.rule.startswith("> "):  # an open low bound: the closed range's edge is refused too
        out.append(r.low)
    if "finite" in r.rule:
        out.append(math.inf)
    return out


RANGED = [(table, spec) for table, (specs, _, _) in TABLES.items()
          for spec in specs if spec.range is not None]


@pytest.mark.parametrize(("table", "spec"), RANGED,
                         ids=[f"{t}:{s.name}" for t, s in RANGED])
def test_a_range_only_excludes_values_the_validation_refuses(table: str, spec: ParamSpec) -> None:
    _, validate, base = TABLES[table]
    assert spec.range is not None and spec.range.holds(spec.default), "default outside range"
    for value in _outside(spec):
        with pytest.raises(ParameterError) as err:
            validate({**base, spec.name: value})
        assert err.value.name == spec.name, (value, err.value)


def test_ranges_are_where_the_validation_has_one() -> None:
    """The rows users tune most carry a range; a .nan-means-no-limit row cannot have one."""
    ranged = {s.name for _, s in RANGED}
    assert {"wheel_radius", "wheel_separation", "left_wheel_sign", "publish_rate",
            "max_wheel_speed", "wheel_command_rate", "joint_state_rate",
            "follower.min_alignment"} <= ranged
    assert "linear.x.max_velocity" not in ranged and "max_wheel_velocity" not in ranged


# --- the type rule: what ROS hands over in another type with the same meaning ---------


def spec_of(name: str) -> ParamSpec:
    return next(s for s in ODOMETRY_PARAMS + CMD_VEL_PARAMS if s.name == name)


def test_an_integer_is_taken_as_the_double_it_means() -> None:
    radius = spec_of("wheel_radius")
    assert as_declared_type(radius, 1) == 1.0 and type(as_declared_type(radius, 1)) is float
    diagonal = spec_of("pose_covariance_diagonal")
    assert as_declared_type(diagonal, [1, 2, 3, 4, 5, 6]) == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert all(type(v) is float for v in as_declared_type(diagonal, [1, 2, 3, 4, 5, 6]))
    bits = spec_of("encoder_counter_bits")
    assert as_declared_type(bits, 16.0) == 16 and type(as_declared_type(bits, 16.0)) is int
    # Not the same meaning: left alone, for rclpy to refuse the type.
    assert as_declared_type(radius, True) is True
    assert as_declared_type(radius, "fast") == "fast"
    assert as_declared_type(bits, 16.5) == 16.5


def test_ros2_param_load_reads_numbers_back_as_strings(tmp_path: Path) -> None:
    """The cause of issue 17's ``wheel_noise_k_left: must be a number, got '1e-05'``:
    ``ros2 param dump`` writes ``1.0e-05`` (yaml.dump), and rclpy's loader re-reads every
    value as ``yaml.safe_load(str(value))``; ``str(1e-05)`` is ``'1e-05'``, which YAML 1.1
    takes for a string (no dot), as it does ``'nan'``; a list holding one becomes one
    string. The type rule reads them as rcl reads a number."""
    dump = tmp_path / "dump.yaml"
    dump.write_text(yaml.dump({"/odometry_node": {"ros__parameters": {
        "wheel_noise_k_left": 1e-05, "twist_covariance_diagonal": [0.001, 1e-06, 1.0e6],
        "linear.x.max_velocity": math.nan, "max_wheel_speed": math.inf}}}))
    loaded = {name: Parameter.from_parameter_msg(msg).value
              for name, msg in parameter_dict_from_yaml_file(str(dump)).items()}
    assert loaded["wheel_noise_k_left"] == "1e-05"  # what the node receives
    assert loaded["twist_covariance_diagonal"] == "[0.001, 1e-06, 1000000.0]"
    assert loaded["linear.x.max_velocity"] == "nan"
    assert as_declared_type(spec_of("wheel_noise_k_left"), "1e-05") == 1e-05
    assert as_declared_type(spec_of("twist_covariance_diagonal"),
                            loaded["twist_covariance_diagonal"]) == [0.001, 1e-06, 1.0e6]
    assert math.isnan(as_declared_type(spec_of("linear.x.max_velocity"), "nan"))
    assert as_declared_type(spec_of("max_wheel_speed"), loaded["max_wheel_speed"]) == math.inf


# --- the real nodes ------------------------------------------------------------------------


@pytest.mark.dds
@pytest.mark.parametrize("name", sorted(NODES))
def test_every_parameter_is_declared_as_its_row_says(name: str) -> None:
    node_class, specs = NODES[name]
    with built(node_class, "--params-file", str(CONFIG)) as node:
        for spec in specs:
            d = node.describe_parameter(spec.name)
            assert d.description == spec.description, spec.name
            assert d.type == TYPE[spec.kind], spec.name
            assert d.dynamic_typing is False and d.read_only == spec.read_only, spec.name
            r = spec.range
            ranges = [(x.from_value, x.to_value, x.step)
                      for x in [*d.floating_point_range, *d.integer_range]]
            assert ranges == ([] if r is None else [(r.low, r.high, r.step)]), spec.name
            assert d.additional_constraints == (r.rule if r else ""), spec.name
            if r is not None:
                lists = d.floating_point_range if spec.kind == "double" else d.integer_range
                assert len(lists) == 1, spec.name


def _set(node: Node, name: str, value: Any) -> Any:
    return node.set_parameters([Parameter(name, value=value)])[0]


@pytest.mark.dds
def test_an_integer_for_a_double_keeps_the_type_double(tmp_path: Path) -> None:
    """``-p wheel_radius:=1``, a YAML ``1`` and a runtime set of ``2``: all doubles."""
    params = tmp_path / "p.yaml"
    params.write_text("/**:\n  ros__parameters:\n    wheel_separation: 1\n"
                      "    pose_covariance_diagonal: [1, 1, 1, 1, 1, 1]\n")
    with built(OdometryNode, "--params-file", str(params), "-p", "wheel_radius:=1") as node:
        for name in ("wheel_radius", "wheel_separation"):
            p = node.get_parameter(name)
            assert (p.type_, p.value) == (Parameter.Type.DOUBLE, 1.0), name
        diag = node.get_parameter("pose_covariance_diagonal")
        assert diag.type_ == Parameter.Type.DOUBLE_ARRAY and list(diag.value) == [1.0] * 6
        assert _set(node, "wheel_radius", 2).successful
        p = node.get_parameter("wheel_radius")
        assert (p.type_, p.value) == (Parameter.Type.DOUBLE, 2.0)
        assert node.odometry._pipeline.settings.geometry.wheel_radius == 2.0  # applied, a float
        assert _set(node, "twist_covariance_diagonal", [1, 2, 3, 4, 5, 6]).successful
        assert node.get_parameter("twist_covariance_diagonal").type_ == (
            Parameter.Type.DOUBLE_ARRAY)
        # A type with another meaning is refused, and the type stays.
        refused = _set(node, "wheel_radius", "fast")
        assert not refused.successful and "type" in refused.reason.lower()
        assert node.get_parameter("wheel_radius").type_ == Parameter.Type.DOUBLE


@pytest.mark.dds
def test_range_and_read_only_refuse_at_runtime_and_the_node_keeps_its_value() -> None:
    with built(OdometryNode, "--params-file", str(CONFIG)) as node:
        out = _set(node, "wheel_radius", -1.0)
        assert not out.successful and "wheel_radius" in out.reason
        open_bound = _set(node, "wheel_radius", 0.0)  # in the closed range, refused by "> 0"
        assert not open_bound.successful and "wheel_radius" in open_bound.reason
        read_only = _set(node, "left_wheel_names", ["other_joint"])
        assert not read_only.successful and "read-only" in read_only.reason
        assert node.get_parameter("wheel_radius").value == 0.042
        assert list(node.get_parameter("left_wheel_names").value) == ["left_wheel_joint"]


@pytest.mark.dds
@pytest.mark.parametrize("node_class", [OdometryNode, CmdVelNode, SimNode, PathFollowerNode],
                         ids=lambda c: c.__name__)
def test_a_length_under_1_mm_is_refused_at_runtime_as_at_start(node_class: type[Node]) -> None:
    """wheel_separation 1e-9 is inside ROS's range (> 0) but no robot's: a set is refused
    with the line the start gives, and the node keeps its value."""
    with built(node_class, "--params-file", str(CONFIG)) as node:
        before = node.get_parameter("wheel_separation").value
        for name in ("wheel_separation", "wheel_radius"):
            out = _set(node, name, 1e-9)
            assert not out.successful, name
            assert out.reason.endswith(f"'{name}': must be at least 0.001 m (1 mm), got "
                                       "1e-09: a length in another unit?"), out.reason
        assert node.get_parameter("wheel_separation").value == before
        assert _set(node, "wheel_separation", 0.001).successful  # the bound itself is fine
    with pytest.raises(ParameterError) as err, built(
            node_class, "--params-file", str(CONFIG), "-p", "wheel_separation:=1e-9"):
        pass
    assert err.value.name == "wheel_separation" and "at least 0.001 m" in str(err.value)


@pytest.mark.dds
def test_a_value_outside_the_range_at_start_is_one_line() -> None:
    with pytest.raises(ParameterError) as err, built(
            OdometryNode, "--params-file", str(CONFIG), "-p", "left_wheel_sign:=0"):
        pass
    assert err.value.name == "left_wheel_sign" and "-1 or 1" in str(err.value)
    with pytest.raises(ParameterError) as err, built(OdometryNode, "-p", "wheel_radius:=fast"):
        pass
    assert err.value.name == "wheel_radius" and "number" in str(err.value)


class _Bare(Node):
    """A plain rclpy node of the odometry node's name: rclpy's own declare, the oracle."""

    def __init__(self, context: Any) -> None:
        super().__init__("odometry_node", context=context)


@pytest.mark.dds
@pytest.mark.parametrize(("name", "text"), [
    ("wheel_radius", '"0.033"'), ("encoder_counter_bits", "'16'"),
    ("pose_covariance_diagonal", '"[0.1, 0.1, 0.1, 0.1, 0.1, 0.1]"')])
def test_a_quoted_number_is_refused_at_start_by_every_node_and_tool(
        name: str, text: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 39 item 3: ``wheel_radius: "0.033"`` was refused by replay and taken by the
    node, whose start read the string as the number (the runtime rule ``ros2 param load``
    needs, which stays: test_the_nodes_own_dump_loads_back). rcl reads a quoted value as
    a string, and rclpy's ``declare_parameter`` with the type fixed refuses it."""
    from rclpy.exceptions import InvalidParameterTypeException

    from diffdrive_odom.ros.parameters import descriptor
    from diffdrive_odom.tools.cli import main as cli

    from rosutil import assert_refused_in_process

    params = tmp_path / "p.yaml"
    values = {**VALID, name: text}
    params.write_text("/**:\n  ros__parameters:\n" + "".join(
        f"    {k}: {v}\n" for k, v in values.items()), encoding="utf-8")
    spec = spec_of(name)
    with built(_Bare, "--params-file", str(params)) as bare, pytest.raises(
            InvalidParameterTypeException, match="of type 'STRING'"):
        bare.declare_parameter(name, spec.default, descriptor(spec))
    takers = [(cls, specs) for cls, specs in NODES.values()
              if name in {s.name for s in specs}]
    assert len(takers) >= 2
    for node_class, _ in takers:
        if node_class is OdometryLifecycleNode:  # starts, so that the value can be fixed
            with built(node_class, "--params-file", str(params)) as node:
                assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
            continue
        assert_refused_in_process(node_class, name, ["--params-file", str(params)])
    for tool, extra in (("replay", ["--eval"]), ("calibrate", [])):
        assert cli([tool, str(tmp_path / "bag"), "--params-file", str(params), *extra]) == 2
        lines = capsys.readouterr().err.splitlines()
        assert len(lines) == 1 and f"invalid parameter '{name}'" in lines[0], lines
        assert "quoted, so a string" in lines[0], lines


@pytest.mark.dds
def test_a_runtime_typo_names_the_closest_parameter() -> None:
    """rclpy 7.1 says ``Invalid access to undeclared parameter(s): []``."""
    with built(OdometryNode, "--params-file", str(CONFIG)) as node:
        with pytest.raises(ParameterNotDeclaredException) as err:
            _set(node, "wheel_radious", 0.05)
        assert "'wheel_radious' (did you mean wheel_radius?)" in str(err.value)
        with pytest.raises(ParameterNotDeclaredException) as err:
            _set(node, "wheel_command_rate", 10.0)
        assert "a parameter of cmd_vel_node" in str(err.value)
        assert _set(node, "use_sim_time", False).successful  # rclpy's own are known


@pytest.mark.dds
@pytest.mark.parametrize("name", ["odometry_node", "cmd_vel_node", "sim_node"])
def test_the_nodes_own_dump_loads_back(name: str, tmp_path: Path) -> None:
    """What ``ros2 param dump`` writes, loaded as ``ros2 param load`` does (rclpy's reader,
    then one set per parameter, as the parameter service does): every parameter that is
    not read-only is taken back unchanged."""
    node_class, specs = NODES[name]
    with built(node_class, "--params-file", str(CONFIG)) as node:
        names = [s.name for s in specs]
        before = {n: node.get_parameter(n).value for n in names}
        dump = tmp_path / "dump.yaml"
        dump.write_text(yaml.dump({f"/{name}": {"ros__parameters": {
            n: list(v) if isinstance(v, (list, tuple)) or hasattr(v, "tolist") else v
            for n, v in before.items()}}}))
        read_only = {s.name for s in specs if s.read_only}
        for pname, msg in parameter_dict_from_yaml_file(str(dump)).items():
            result = node.set_parameters([Parameter.from_parameter_msg(msg)])[0]
            assert result.successful == (pname not in read_only), (pname, result.reason)
        for n in names:
            after = node.get_parameter(n).value
            assert _same(after, before[n]), (n, after, before[n])


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if not isinstance(a, (str, int, float, bool)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b) and type(a) is type(b)
