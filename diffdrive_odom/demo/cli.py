"""``diffdrive-odom demo`` command line: options -> :func:`.loop.run` -> the table."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from diffdrive_odom.core.motion import routes
from diffdrive_odom.tools.cli import command_parser, invocation

from . import interrupts
from .settings import DEFAULT_PARAMS, PROGRAM, ROUTES, DemoError, DemoOptions, parse_override

SHORT_SIDE = 1.0


def _parser() -> argparse.ArgumentParser:
    ap = command_parser("demo", "Closed-loop demo: path_follower_node + cmd_vel_node + "
                        "sim_node + odometry_node over DDS drive UMBmark on the odometry; "
                        "calibrates from the run, prints the table, writes a plot and a bag.")
    ap.add_argument("--route", default="umbmark", choices=list(ROUTES),
                    help="squares to drive (default: UMBmark, 4 m square CW then CCW; the "
                         "UMBmark calibration row needs both directions)")
    ap.add_argument("--size", type=float, default=None,
                    help="side of the squares [m] (default per route: "
                         f"{routes.DEFAULT_SIZE['umbmark']:g} m UMBmark, "
                         f"{routes.DEFAULT_SIZE['square']:g} m square)")
    ap.add_argument("--linear", type=float, default=0.4,
                    help="the follower's desired speed [m/s]")
    ap.add_argument("--angular", type=float, default=2.0,
                    help="the largest turn rate the follower asks for [rad/s]")
    ap.add_argument("--short", action="store_true",
                    help=f"UMBmark with {SHORT_SIDE:g} m squares instead (about 25 s of "
                         "simulated time)")
    ap.add_argument("--output", default="demo_output", help="output directory")
    ap.add_argument("--params-file", default=str(DEFAULT_PARAMS),
                    help="params YAML for all four nodes")
    ap.add_argument("--sim-param", action="append", default=[], metavar="NAME:=VALUE",
                    help="override a sim_node parameter (repeatable), e.g. "
                         "true_right_wheel_radius:=0.0505")
    ap.add_argument("--timeout", type=float, default=150.0, help="give up after [s] (wall)")
    ap.add_argument("--domain-id", type=int, default=None,
                    help="ROS_DOMAIN_ID for the run (default: a random one)")
    ap.add_argument("--no-bag", action="store_true", help="do not write the bag")
    ap.add_argument("--no-plot", action="store_true", help="do not write the PNG")
    return ap


def options(args: argparse.Namespace) -> DemoOptions:
    """The parsed command line as run options (DemoError for a bad one)."""
    route = "umbmark" if args.short else args.route
    side = SHORT_SIDE if args.short else (
        args.size if args.size is not None else routes.DEFAULT_SIZE[route])
    return DemoOptions(
        route=route, side=side, output=Path(args.output), params_file=Path(args.params_file),
        speed=args.linear, max_angular=args.angular,
        sim_overrides=dict(parse_override(t) for t in args.sim_param),
        timeout=args.timeout, write_bag=not args.no_bag, write_plot=not args.no_plot,
        domain_id=args.domain_id,
    )


def parse(argv: Sequence[str]) -> DemoOptions:
    """The command line as run options, checked before anything starts (DemoError)."""
    from .settings import check_options, load_settings

    opts = options(_parser().parse_args(list(argv)))
    check_options(opts)
    load_settings(opts)
    return opts


def main(argv: Sequence[str] | None = None) -> int:
    """``diffdrive-odom demo``: 0 on success, 1 if the run failed, 2 on bad options."""
    try:
        opts = parse(sys.argv[1:] if argv is None else argv)
    except DemoError as err:
        print(f"[{PROGRAM}] {err}", file=sys.stderr)
        return 2
    return _run(opts)


def _run(opts: DemoOptions) -> int:
    """The run itself: Ctrl-C or SIGTERM stop it cleanly (exit 130, every node stopped)."""
    from .loop import run

    if opts.write_plot:  # a missing matplotlib is said before the drive, not after it
        import matplotlib  # noqa: F401

    try:
        with interrupts.handled():
            kinds = " then ".join("CW" if cw else "CCW" for cw in opts.squares)
            print(f"[{PROGRAM}] driving {opts.route} ({opts.side:g} m squares, {kinds}) with "
                  f"path_follower_node at {opts.speed:g} m/s, in lockstep with the "
                  "simulation...", flush=True)
            result = run(opts)
    except DemoError as err:
        print(f"[{PROGRAM}] failed: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"[{PROGRAM}] interrupted; every node stopped", file=sys.stderr)
        return 130
    print(result.table(invocation()))
    return 0
