"""``localize``: the localization chain in one process (``detect_triangulate`` + ``hand_eye``).

The two nodes of ``eye-in-hand launch`` (docs/ros.md), built in one process (an executor per
node, each on its own thread), with their usual names, namespaces, parameters and topics. The
difference is the hand-off: each located stereo pair goes from ``detect_triangulate``'s
worker thread straight to ``hand_eye`` (:meth:`~eye_in_hand.nodes.hand_eye.HandEyeNode.deliver`, a
:class:`~eye_in_hand.ros.outputs.LocatedFrame`), where the separate processes send it through
DDS as ``target/point``, ``target/point_cov``, ``targets/<id>/point_cov`` and
``targets/markers``, and ``hand_eye`` takes it from there. No serialisation, no DDS hop and
no executor wake-up per message: ``hand_eye`` wakes once per pair. The camera-frame topics are
still published for anyone else who subscribes; ``hand_eye``'s outputs are the same messages as
with separate processes (``test/nodes/test_localize.py``).

Usage (one parameter file for both nodes, as ``eye-in-hand launch``)::

    python -m eye_in_hand.nodes.localize [--namespace NS] [--set NODE.NAME:=VALUE ...] \\
        --ros-args --params-file config/eye_in_hand.yaml
    eye-in-hand launch --composed ...          # the same, supervised
    ros2 run eye_in_hand localize --ros-args --params-file ...

``--namespace`` is the root namespace (``detect_triangulate`` runs in ``<NS>/stereo`` with its
outputs remapped to the root, as the launcher does); ``--set`` gives one node a string
parameter after the file (``eye-in-hand launch --calibration/--hand-eye``).
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
from collections.abc import Sequence
from typing import Any

from eye_in_hand.threads import blas_env_defaults, name_os_thread

os.environ.update(blas_env_defaults(os.environ))   # as detect_triangulate (see there)

import rclpy  # noqa: E402
from rclpy.executors import ExternalShutdownException  # noqa: E402

from eye_in_hand.errors import InputError  # noqa: E402
from eye_in_hand.launcher import NODES, node_ros_args  # noqa: E402
from eye_in_hand.nodes.detect_triangulate import DetectTriangulateNode  # noqa: E402
from eye_in_hand.nodes.hand_eye import HandEyeNode  # noqa: E402
from eye_in_hand.ros.executor import LeanExecutor  # noqa: E402
from eye_in_hand.ros.node_main import guard, prepare_process  # noqa: E402
from eye_in_hand.ros.params import refuse_undeclared_overrides  # noqa: E402

__all__ = ["NAME", "LocalizationChain", "main"]

NAME = "localize"
_SPECS = {s.name: s for s in NODES if s.name in ("detect_triangulate", "hand_eye")}


class LocalizationChain:
    """``detect_triangulate`` and ``hand_eye`` (``in_process``) in this process, linked.

    Args:
        root_namespace: the launcher's root namespace.
        overrides: node name -> string parameters ``(name, value)`` after the parameter file.
        parameters: node name -> ``rclpy.Parameter`` overrides (``Node``'s
            ``parameter_overrides``, for a program that builds the chain itself).
        **kwargs: for both nodes' ``Node`` (``context``, ...).
    """

    def __init__(self, root_namespace: str = "/",
                 overrides: dict[str, list[tuple[str, str]]] | None = None,
                 parameters: dict[str, list[Any]] | None = None, **kwargs: Any) -> None:
        overrides, parameters = overrides or {}, parameters or {}

        def node_kwargs(name: str) -> dict[str, Any]:
            cli = node_ros_args(_SPECS[name], root_namespace=root_namespace,
                                overrides=overrides.get(name, ()))
            return {"cli_args": ["--ros-args", *cli],
                    "parameter_overrides": parameters.get(name, []), **kwargs}

        self.detect = DetectTriangulateNode(**node_kwargs("detect_triangulate"))
        try:
            self.hand_eye = HandEyeNode(in_process=True, **node_kwargs("hand_eye"))
        except BaseException:
            self.detect.destroy_node()
            raise
        self.hand_eye.expect_targets(self.detect.target_ids)
        self.detect.frame_sinks.append(self.hand_eye.deliver)

    @property
    def nodes(self) -> tuple[Any, Any]:
        return (self.detect, self.hand_eye)

    def destroy(self) -> None:
        """Stop the detector's worker first (no hand-off after), then both nodes."""
        self.detect.destroy_node()
        self.hand_eye.destroy_node()


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=NAME, description="detect_triangulate + hand_eye in one process (ROS arguments "
        "after --ros-args, e.g. --params-file FILE)")
    parser.add_argument("--namespace", default="/", metavar="NS",
                        help="root namespace (default /)")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.NAME:=VALUE",
                        help="a string parameter of one node after the parameter file")
    parser.add_argument("--debug", action="store_true", help="tracebacks for internal errors")
    return parser.parse_args(argv)


def _overrides(items: Sequence[str]) -> dict[str, list[tuple[str, str]]]:
    out: dict[str, list[tuple[str, str]]] = {}
    for item in items:
        node, _, rest = item.partition(".")
        name, sep, value = rest.partition(":=")
        if node not in _SPECS or not name or not sep:
            raise InputError(f"--set {item!r}: expected NODE.NAME:=VALUE with NODE one of "
                             f"{', '.join(_SPECS)}")
        out.setdefault(node, []).append((name, value))
    return out


#: the OS name of the thread that spins detect_triangulate's executor (hand_eye's spins on the
#: main thread): each node's CPU shows per thread (``top -H``, eye_in_hand.threads)
DETECT_EXECUTOR_THREAD = "detect_exec"


def _spin(executor: Any) -> None:
    name_os_thread()      # DETECT_EXECUTOR_THREAD, its Python name, for the OS too
    try:
        executor.spin()
    except ExternalShutdownException:
        pass


def main(args: list[str] | None = None) -> None:
    """Console entry point: ``ros2 run eye_in_hand localize``."""
    argv = list(sys.argv[1:] if args is None else args)
    split = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    own, ros_args = argv[:split], argv[split:]

    def body() -> None:
        opts = _parse(own)
        overrides = _overrides(opts.set)
        prepare_process()
        rclpy.init(args=[NAME, *ros_args])
        chain = None
        # one executor per node, each on its own thread: a wake-up for a robot pose then
        # builds hand_eye's wait set only, one for an image detect_triangulate's only
        executors = [LeanExecutor(), LeanExecutor()]
        spinner = None
        try:
            chain = LocalizationChain(opts.namespace, overrides)
            for node, executor in zip(chain.nodes, executors, strict=True):
                refuse_undeclared_overrides(node, ros_args)
                executor.add_node(node)
            spinner = threading.Thread(target=_spin, args=(executors[0],),
                                       name=DETECT_EXECUTOR_THREAD, daemon=True)
            spinner.start()
            executors[1].spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            for executor in executors:
                executor.shutdown(timeout_sec=5.0)
            if spinner is not None:
                spinner.join(timeout=5.0)
            if chain is not None:
                chain.destroy()
            rclpy.try_shutdown()

    code = guard(NAME, body, argv)
    if code:
        raise SystemExit(code)


if __name__ == "__main__":
    main()
