"""``eye-in-hand launch``: start stereo_capture, detect_triangulate and hand_eye as processes.

Example::

    eye-in-hand launch --params config/eye_in_hand.yaml
    eye-in-hand launch --params my.yaml --skip stereo_capture     # images come from a bag

One ROS parameter file configures all three nodes (``/**/<node>:`` sections). Output lines are
prefixed with ``[node]``; Ctrl-C is forwarded; the command exits non-zero when a node dies.
``launch/eye_in_hand.launch.py`` is the same bring-up for ``ros2 launch`` on a ROS install.
"""
from __future__ import annotations

import argparse

HELP = "start stereo_capture, detect_triangulate and hand_eye as separate processes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``eye-in-hand launch``."""
    parser.add_argument("--params", metavar="FILE",
                        help="ROS parameter file for all nodes (default: config/eye_in_hand.yaml)")
    parser.add_argument("--skip", nargs="+", default=[], metavar="NODE",
                        choices=("stereo_capture", "detect_triangulate", "hand_eye"),
                        help="nodes not to start (e.g. stereo_capture when a bag is replayed)")
    parser.add_argument("--namespace", default="/", metavar="NS",
                        help="root namespace of every node and topic (default /)")
    parser.add_argument("--duration", type=float, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C)")


def run(args: argparse.Namespace) -> int:
    """Start the nodes and supervise them until Ctrl-C, --duration or a node's exit."""
    from eye_in_hand.errors import InputError
    from eye_in_hand.launcher import NODES, Launcher, default_params_file

    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration: must be positive, got {args.duration}")
    params = args.params or default_params_file()
    # bad input is one line here, not a traceback from rcl in every node
    from eye_in_hand.errors import ConfigError
    from eye_in_hand.ros.names import check_parameter_text, topic_name_problem
    from eye_in_hand.yamlfile import printable, read_yaml_file

    ns = "/" + args.namespace.strip("/")
    problem = None if ns == "/" else topic_name_problem(ns)
    if problem is not None:
        raise InputError(f"--namespace {printable(args.namespace)!r}: not a valid namespace "
                         f"({problem})")
    check_parameter_text(str(params), "--params")  # rcl takes it as UTF-8 text
    if not isinstance(read_yaml_file(params, "parameter file"), dict):
        raise ConfigError(f"{printable(params)}: parameter file must map node names to "
                          "'ros__parameters'")
    nodes = [n.name for n in NODES if n.name not in args.skip]
    launcher = Launcher(params, nodes, root_namespace=args.namespace)
    print(f"eye-in-hand launch: starting {', '.join(nodes)} with {params}", flush=True)
    return launcher.run(args.duration)
