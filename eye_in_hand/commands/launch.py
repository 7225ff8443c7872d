"""``eye-in-hand launch``: start stereo_capture, detect_triangulate and hand_eye as processes.

Example::

    eye-in-hand launch --params config/eye_in_hand.yaml
    eye-in-hand launch --params my.yaml --skip stereo_capture     # images come from a bag
    eye-in-hand launch --calibrate --params my_calibration.yaml  # hand-eye at a live cell

One ROS parameter file configures all three nodes (``/**/<node>:`` sections). Output lines are
prefixed with ``[node]``; Ctrl-C is forwarded. A node that crashes is restarted after a bounded
exponential back-off; one that crashes more than ``--max-restarts`` times within
``--restart-window`` seconds stops the launch (non-zero exit, naming it). ``--no-respawn``:
the first node that exits stops everything.
``launch/eye_in_hand.launch.py`` is the same bring-up for ``ros2 launch`` on a ROS install.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from eye_in_hand.commands.common import bounded
from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.launcher import CALIBRATION_NODES, NODES, Launcher, default_params_file
from eye_in_hand.nodes.parameters import check_parameter_file_keys
from eye_in_hand.ros.names import check_namespace, check_parameter_text
from eye_in_hand.ros.params import check_parameter_file
from eye_in_hand.yamlfile import printable, read_yaml_file

HELP = "start stereo_capture, detect_triangulate and hand_eye as separate processes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand launch``."""
    parser.add_argument("--params", metavar="FILE",
                        help="ROS parameter file for all nodes (default: config/eye_in_hand.yaml)")
    parser.add_argument("--calibration", metavar="DIR",
                        help="stereo calibration directory (left.yaml + right.yaml, from "
                             "'calibrate stereo'): replaces the parameter file's "
                             "detect_triangulate calibration_dir (with --calibrate: hand_eye's; "
                             "default: the parameter file's)")
    parser.add_argument("--hand-eye", metavar="FILE",
                        help="hand_eye.yaml (from 'calibrate handeye'): replaces the parameter "
                             "file's hand_eye hand_eye_file (default: the parameter file's)")
    parser.add_argument("--calibrate", action="store_true",
                        help="hand-eye calibration at a live cell: stereo_capture and hand_eye "
                             "in calibration mode, reading the camera's images (default "
                             "parameter file: config/hand_eye_calibration.yaml); see "
                             "docs/handeye.md")
    parser.add_argument("--composed", action="store_true",
                        help="run detect_triangulate and hand_eye in one process, the located "
                             "points handed over in memory instead of over DDS (less CPU and "
                             "latency per frame; the same topics; see docs/ros.md)")
    parser.add_argument("--skip", nargs="+", default=[], metavar="NODE",
                        choices=("stereo_capture", "detect_triangulate", "hand_eye"),
                        help="nodes not to start (e.g. stereo_capture when a bag is replayed)")
    parser.add_argument("--namespace", default="/", metavar="NS",
                        help="root namespace of every node and topic (default /)")
    parser.add_argument("--duration", type=bounded(0, 1e7, "s", lo_open=True), metavar="S",
                        help="stop after S seconds, (0, 1e7] (default: run until Ctrl-C)")
    parser.add_argument("--no-respawn", action="store_true",
                        help="do not restart a node that exits: stop every node instead")
    parser.add_argument("--respawn-delay", type=bounded(0, 8, "s"), default=0.5, metavar="S",
                        help="back-off before restarting a crashed node, doubled for each "
                             "further restart within the window, at most 8 s (default 0.5)")
    parser.add_argument("--max-restarts", type=bounded(0, 1000, integer=True), default=5,
                        metavar="N",
                        help="restarts of one node allowed within --restart-window, 0 to "
                             "1000; one more stops the launch (default 5)")
    parser.add_argument("--restart-window", type=bounded(0, 86400, "s", lo_open=True),
                        default=60.0, metavar="S",
                        help="window of --max-restarts in seconds (default 60)")


def run(args: argparse.Namespace) -> int:
    """Start the nodes and supervise them until Ctrl-C, --duration or a node's exit."""
    params = args.params or default_params_file(
        "hand_eye_calibration.yaml" if args.calibrate else "eye_in_hand.yaml")
    # bad input is one line here, not a traceback from rcl in every node
    ns = check_namespace(args.namespace)
    check_parameter_text(str(params), "--params")  # rcl takes it as UTF-8 text
    if not isinstance(read_yaml_file(params, "parameter file"), dict):
        raise ConfigError(f"{printable(params)}: parameter file must map node names to "
                          "'ros__parameters'")
    check_parameter_file(params)  # rcl's own parser: never a crash-looping node
    catalogue = CALIBRATION_NODES if args.calibrate else NODES
    nodes = [n.name for n in catalogue if n.name not in args.skip]
    if not nodes:
        raise InputError("--skip: no node left to start")
    check_parameter_file_keys(params, used=nodes)  # a mistyped key would run on its default
    overrides = _overrides(args)
    launcher = Launcher(params, nodes, root_namespace=ns, overrides=overrides,
                        respawn=not args.no_respawn, respawn_delay_s=args.respawn_delay,
                        max_restarts=args.max_restarts, restart_window_s=args.restart_window,
                        calibrate=args.calibrate, composed=args.composed)
    what = ", ".join(nodes) + (" (detect_triangulate + hand_eye in one process)"
                               if args.composed else "")
    print(f"eye-in-hand launch: starting {what} with {params}", flush=True)
    return launcher.run(args.duration)


def _overrides(args: argparse.Namespace) -> dict[str, list[tuple[str, str]]]:
    """``--calibration`` / ``--hand-eye`` as node parameters, checked here: a missing file is
    one line now, not a node that refuses to start."""

    out: dict[str, list[tuple[str, str]]] = {}
    if args.calibration is not None:
        check_parameter_text(str(args.calibration), "--calibration")
        cdir = Path(args.calibration)
        if not (cdir / "left.yaml").is_file() or not (cdir / "right.yaml").is_file():
            raise InputError(f"--calibration: {cdir} has no left.yaml + right.yaml (a folder "
                             "written by 'eye-in-hand calibrate stereo')")
        node = "hand_eye" if args.calibrate else "detect_triangulate"
        out.setdefault(node, []).append(("calibration_dir", str(cdir.resolve())))
    if args.hand_eye is not None:
        check_parameter_text(str(args.hand_eye), "--hand-eye")
        if not Path(args.hand_eye).is_file():
            raise InputError(f"--hand-eye: {args.hand_eye}: file not found (a hand_eye.yaml "
                             "written by 'eye-in-hand calibrate handeye')")
        out.setdefault("hand_eye", []).append(("hand_eye_file",
                                               str(Path(args.hand_eye).resolve())))
    return out

