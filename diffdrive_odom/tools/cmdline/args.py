"""The command-line flags replay, calibrate and eval share, and what they resolve to.

One definition per flag, so the tools that run the node's estimator take its settings
the same way (``--params-file``/``-p`` in rcl's order, ``--node-name``, ``--namespace``)
and the tools that read ground truth find it the same way (``--ground-truth``,
``--child-frame``) and place it on the robot the same way (``--reference-offset``).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.settings.rcl import ParamSource, ParamValue, resolve_parameters
from diffdrive_odom.settings.registry import unknown_parameters_report
from diffdrive_odom.settings.shadowed import shadowed_overrides_line
from diffdrive_odom.tools.cmdline.outputs import output_problem

NODE_NAME = "odometry_node"
DEFAULT_REFERENCE = "/ground_truth/pose"  # the ground-truth topic looked for first


def fail(prefix: str, text: str) -> int:
    """Say ``text`` on stderr after the tool's ``prefix``; the exit status of a usage error."""
    print(f"{prefix} {text}", file=sys.stderr)
    return 2


def load_settings(
    params: str | Path | Sequence[ParamSource], node_name: str = NODE_NAME,
    namespace: str = "/", settled: Mapping[str, ParamValue] | None = None,
    prefix: str | None = "[diffdrive-odom]",
) -> OdometrySettings:
    """Return the node's settings from its params files and ``-p`` overrides.

    Sources are in command-line order, resolved as rclpy resolves them for this node
    name and namespace, and validated exactly as the node does. ``settled``: values a
    tool's own flag implies (``replay --online-calibration``, calibrate: use_imu), set
    after every source, as no ``-p`` can be (a node's own section beats it). The
    unknown names and a lost ``-p`` are said after the tool's ``prefix`` (None: not said,
    for a second load of the same sources).
    """
    sources = [("file", str(params))] if isinstance(params, (str, Path)) else list(params)
    values = {**resolve_parameters(sources, node_name, namespace), **(settled or {})}
    if prefix is not None:
        shadowed = shadowed_overrides_line(sources, node_name, namespace, settled or {})
        for line in (*unknown_parameters_report(list(values)), shadowed):
            if line:
                print(f"{prefix} {line}", file=sys.stderr)
    return odometry_settings(values, "/" + namespace.strip("/"))


class _RosParam(argparse.Action):
    """Keeps ``--params-file`` and ``-p`` in one list, in command-line order (rcl's order)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        kind = "file" if option_string == "--params-file" else "param"
        namespace.ros_params = [*(getattr(namespace, "ros_params", None) or []), (kind, values)]


def add_param_arguments(ap: argparse.ArgumentParser, required: bool, file_help: str) -> None:
    """Add the flags every tool running the node's estimator takes its settings from.

    ``--params-file`` / ``-p`` go into one ordered list (rcl's order), then
    ``--node-name`` and ``--namespace``.
    """
    ap.add_argument("--params-file", required=required, action=_RosParam, dest="ros_params",
                    metavar="FILE", help=file_help)
    ap.add_argument("-p", "--param", action=_RosParam, dest="ros_params", metavar="NAME:=VALUE",
                    help="parameter override, as the node's -p (repeatable; order with "
                         "--params-file matters as in rcl; default: none)")
    ap.add_argument("--node-name", default=NODE_NAME,
                    help="node name the params are resolved for (-r __node:=)")
    ap.add_argument("--namespace", default="/",
                    help="node namespace (-r __ns:=): params resolution and frame prefix")


def settings_from_args(args: argparse.Namespace, prefix: str | None,
                       settled: Mapping[str, ParamValue] | None = None,
                       ) -> OdometrySettings | str:
    """The settings :func:`add_param_arguments`' flags give, or the one line why not.

    ``prefix`` and ``settled``: as :func:`load_settings` takes them.
    """
    try:
        return load_settings(args.ros_params, args.node_name, args.namespace, settled, prefix)
    except ParameterError as err:
        return str(err)
    except OSError as err:
        return f"--params-file: {err}"


def add_reference_arguments(ap: argparse.ArgumentParser, offset_default: str) -> None:
    """``--ground-truth``, ``--child-frame``, ``--reference-offset``: find and place the reference.

    ``offset_default``: what the tool does without ``--reference-offset`` (its help's end).
    """
    ap.add_argument("--ground-truth", default=None, metavar="TOPIC",
                    help="reference topic: PoseStamped, PoseWithCovarianceStamped, Odometry, "
                    f"or TransformStamped on /tf (default: {DEFAULT_REFERENCE}, else the "
                    "bag's only ground-truth topic, e.g. sim_node's /ground_truth/odom)")
    ap.add_argument("--child-frame", default=None, metavar="FRAME",
                    help="reference child frame on /tf (default: the only one there)")
    add_offset_argument(ap, offset_default)


def add_offset_argument(ap: argparse.ArgumentParser, default: str) -> None:
    """``--reference-offset X,Y,YAW``: where the reference is mounted on the robot."""
    ap.add_argument("--reference-offset", type=reference_offset, default=None,
                    metavar="X,Y,YAW", help="the pose of the reference's frame in base_link "
                    "(REP-103: x forward, y left [m], yaw counter-clockwise [deg]), as the "
                    "base_link -> frame transform gives it: a marker body, camera or antenna "
                    f"off the axle or turned; --reference-offset=-0.1,0.2,90 when X is "
                    f"negative (default: {default})")


def reference_offset(text: str) -> Mount:
    """``X,Y,YAW`` (m, m, deg) as a mount; argparse's error (exit 2) says what is wrong."""
    try:
        x, y, yaw = (float(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"give X,Y,YAW (m, m, deg), got {text!r}") from None
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise argparse.ArgumentTypeError(f"X,Y,YAW must be finite, got {text!r}")
    return Mount(x, y, math.radians(yaw))


def outputs_problem(*outputs: tuple[str, str | None]) -> str | None:
    """Why one of the ``(flag, path)`` outputs asked for cannot be written, or None.

    Checked before any work, so a typo in an output path costs nothing.
    """
    for flag, path in outputs:
        problem = output_problem(path, flag) if path else None
        if problem:
            return problem
    return None
