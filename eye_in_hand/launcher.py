"""Process launcher: the three nodes as separate processes, one parameter file.

With ``composed``, detect_triangulate and hand_eye run in one process instead
(:data:`COMPOSED`, :mod:`eye_in_hand.nodes.localize`): the same names, namespaces and topics.

The equivalent of ``launch/eye_in_hand.launch.py`` for installs without ``ros2 launch``:

=================== ============ ===========================================================
node                namespace    remappings (relative to the root namespace)
=================== ============ ===========================================================
stereo_capture      ``stereo``   ``ee_pose``, ``joint_states`` -> root (sim source)
detect_triangulate  ``stereo``   ``target/point``, ``target/point_cov``,
                                 ``target/debug_image``, ``targets/markers`` -> root (and
                                 with it every ``targets/<id>/...``)
hand_eye            root         (subscribes ``target/point``, ``targets/markers``,
                                 ``ee_pose`` / ``joint_states``)
=================== ============ ===========================================================

Every node's ``diagnostics`` goes to the root ``diagnostics`` topic. So with the default root
namespace ``/`` the cameras are ``/stereo/left/image_raw`` ... (what the simulator's bags hold),
the robot pose is ``/ee_pose`` and the result is ``/target/pose``.

Each child's output lines are prefixed with ``[node]``; Ctrl-C (SIGINT) and SIGTERM are
forwarded to every child.

Supervision: a child that exits on its own (a crash, ``kill -9``) is started again after a
bounded exponential back-off (``respawn_delay_s``, doubled for each restart within
``restart_window_s``, at most ``respawn_max_delay_s``), and the launcher's own lines
(``[launch] ...``) say so. A node that needs more than ``max_restarts`` restarts within
``restart_window_s`` is given up: the others are stopped and the launcher exits non-zero,
naming it. With ``respawn=False`` (``--no-respawn``) the first exit stops everything at once.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from eye_in_hand.errors import ConfigError, InputError
from eye_in_hand.threads import ONE_BLAS_THREAD, blas_env_defaults

__all__ = ["NodeSpec", "NODES", "CALIBRATION_NODES", "COMPOSED", "NODE_ENV_DEFAULTS",
           "node_command", "node_ros_args",
           "node_namespace", "node_remappings", "node_parameters", "Launcher",
           "default_params_file"]


@dataclass(frozen=True)
class NodeSpec:
    """How one node is started."""

    name: str
    module: str
    namespace: str = ""                       # relative to the root namespace
    remaps: tuple[tuple[str, str], ...] = ()  # (from, to); a 'to' without '/' is root-relative
    extra_args: tuple[str, ...] = field(default=())


_TO_ROOT = ("diagnostics",)

#: Environment every node process gets unless the user chose a BLAS thread count
#: (:func:`eye_in_hand.threads.blas_env_defaults`; here and in ``launch/eye_in_hand.launch.py``):
#: one BLAS thread (docs/localization.md "Live latency": OpenBLAS's idle pool threads spin and
#: cost the live chain a core).
NODE_ENV_DEFAULTS = dict(ONE_BLAS_THREAD)

#: The nodes, in start order.
NODES: tuple[NodeSpec, ...] = (
    NodeSpec("stereo_capture", "eye_in_hand.nodes.stereo_capture", "stereo",
             (("ee_pose", "ee_pose"), ("joint_states", "joint_states"))),
    NodeSpec("detect_triangulate", "eye_in_hand.nodes.detect_triangulate", "stereo",
             (("target/point", "target/point"), ("target/point_cov", "target/point_cov"),
              ("target/debug_image", "target/debug_image"),
              ("targets/markers", "targets/markers"))),
    NodeSpec("hand_eye", "eye_in_hand.nodes.hand_eye", ""),
)

#: detect_triangulate and hand_eye in one process (``eye-in-hand launch --composed``,
#: :mod:`eye_in_hand.nodes.localize`): each node's namespace and remappings as above.
COMPOSED = NodeSpec("localize", "eye_in_hand.nodes.localize", "")

#: Calibration mode (``eye-in-hand launch --calibrate``, ``mode:=calibration``): the camera, and
#: hand_eye in calibration mode reading the camera's images (``stereo/left/image_raw``, ...).
CALIBRATION_NODES: tuple[NodeSpec, ...] = (
    NODES[0],
    NodeSpec("hand_eye", "eye_in_hand.nodes.hand_eye", "",
             (("left/image_raw", "stereo/left/image_raw"),
              ("right/image_raw", "stereo/right/image_raw"),
              ("image_raw", "stereo/left/image_raw")),
             ("-p", "mode:=calibration")),
)


def default_params_file(name: str = "eye_in_hand.yaml") -> Path:
    """``config/<name>`` of the source tree, or of the installed share folder."""
    here = Path(__file__).resolve().parent.parent / "config" / name
    if here.is_file():
        return here
    try:  # local: ament_index_python is there only where the package is installed with ament
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("eye_in_hand")) / "config" / name
    except Exception as exc:  # noqa: BLE001 - any failure means: not installed with ament
        raise ConfigError(f"cannot find config/{name}: pass --params FILE") from exc


def _join(root: str, rel: str) -> str:
    root = "/" + root.strip("/")
    return (root.rstrip("/") + "/" + rel.strip("/")) if rel else root


def _yaml_string(value: str) -> str:
    """A string as rcl reads a ``-p name:=value`` (YAML): single-quoted, so that ``123`` or
    ``true`` stays a string."""
    return "'" + value.replace("'", "''") + "'"


def node_namespace(spec: NodeSpec, *, root_namespace: str = "/") -> str:
    """The absolute namespace of one node under ``root_namespace``."""
    return _join(root_namespace, spec.namespace)


def node_remappings(spec: NodeSpec, *, root_namespace: str = "/") -> list[tuple[str, str]]:
    """The remappings ``(from, to)`` of one node under ``root_namespace``: its own (a 'to'
    without a leading '/' is relative to the root namespace) and ``diagnostics`` to the root;
    only those that change a name. The one source of the bring-up's remappings for
    ``eye-in-hand launch``, the composed process and ``launch/eye_in_hand.launch.py``."""
    ns = node_namespace(spec, root_namespace=root_namespace)
    out = []
    for src, dst in list(spec.remaps) + [(t, t) for t in _TO_ROOT]:
        target = _join(root_namespace, dst)
        if target != _join(ns, src):
            out.append((src, target))
    return out


def node_parameters(spec: NodeSpec) -> dict[str, str]:
    """The parameters a node is started with besides the parameter file (``-p name:=value``
    of :attr:`NodeSpec.extra_args`), e.g. ``{"mode": "calibration"}``."""
    args = list(spec.extra_args)
    return dict(args[i + 1].split(":=", 1) for i in range(len(args) - 1) if args[i] == "-p")


def node_ros_args(spec: NodeSpec, *, root_namespace: str = "/",
                  overrides: Sequence[tuple[str, str]] = ()) -> list[str]:
    """The ROS arguments of one node after ``--ros-args`` and the parameter file: its
    namespace, ``overrides`` (string parameters ``(name, value)``, ``-p name:=value``) and
    remappings; as a process's arguments or a node's own ``cli_args`` in a composed process."""
    args = ["-r", f"__ns:={node_namespace(spec, root_namespace=root_namespace)}"]
    for name, value in overrides:
        args += ["-p", f"{name}:={_yaml_string(value)}"]
    for src, target in node_remappings(spec, root_namespace=root_namespace):
        args += ["-r", f"{src}:={target}"]
    return args + list(spec.extra_args)


def node_command(spec: NodeSpec, params_file: str | os.PathLike[str], *,
                 root_namespace: str = "/", python: str = sys.executable,
                 overrides: Sequence[tuple[str, str]] = (),
                 composed_overrides: dict[str, list[tuple[str, str]]] | None = None
                 ) -> list[str]:
    """The command line that starts ``spec`` as a process; ``overrides``: string parameters
    ``(name, value)`` set after the parameter file (``-p name:=value``). :data:`COMPOSED`
    takes its nodes' overrides as ``composed_overrides`` (node name -> parameters)."""
    if spec.name == COMPOSED.name:
        sets = [a for node, items in (composed_overrides or {}).items() for name, value in items
                for a in ("--set", f"{node}.{name}:={value}")]
        return [python, "-u", "-m", spec.module, "--namespace", root_namespace, *sets,
                "--ros-args", "--params-file", str(params_file)]
    args = node_ros_args(spec, root_namespace=root_namespace, overrides=overrides)
    # the namespace, the file, then the overrides: they replace the file's values
    return [python, "-u", "-m", spec.module, "--ros-args", *args[:2],
            "--params-file", str(params_file), *args[2:]]


class Launcher:
    """Start nodes as child processes and supervise them.

    Args:
        params_file: the ROS parameter file given to every node.
        nodes: which nodes (names from :data:`NODES`, or :data:`CALIBRATION_NODES` with
            ``calibrate``), in start order.
        root_namespace: prefix of every node's namespace.
        env: environment of the children (default: this process's), with
            ``OPENBLAS_NUM_THREADS=1`` unless it sets a BLAS thread count
            (:mod:`eye_in_hand.threads`).
        out: where prefixed child output goes (default: stdout).
        respawn: restart a child that exits on its own (see the module docstring).
        respawn_delay_s: back-off before the first restart; doubled for each further restart
            within ``restart_window_s``.
        respawn_max_delay_s: the longest back-off.
        max_restarts: restarts of one node allowed within ``restart_window_s``; one more and
            the launch stops, naming the node.
        restart_window_s: the window of ``max_restarts`` (s).
        calibrate: calibration mode (:data:`CALIBRATION_NODES`).
        overrides: node name -> string parameters ``(name, value)`` that replace the
            parameter file's (``launch --calibration`` / ``--hand-eye``).
        composed: detect_triangulate and hand_eye in one process (:data:`COMPOSED`), with
            the hand-off in memory (:mod:`eye_in_hand.nodes.localize`).
    """

    def __init__(self, params_file: str | os.PathLike[str], nodes: Sequence[str] | None = None,
                 *, root_namespace: str = "/", env: dict[str, str] | None = None,
                 out: IO[str] | None = None, respawn: bool = True,
                 respawn_delay_s: float = 0.5, respawn_max_delay_s: float = 8.0,
                 max_restarts: int = 5, restart_window_s: float = 60.0,
                 calibrate: bool = False,
                 overrides: dict[str, list[tuple[str, str]]] | None = None,
                 composed: bool = False) -> None:
        if not (respawn_delay_s >= 0 and respawn_max_delay_s >= respawn_delay_s):
            raise InputError(f"respawn delays: need 0 <= first ({respawn_delay_s}) <= max "
                             f"({respawn_max_delay_s})")
        if max_restarts < 0 or not restart_window_s > 0:
            raise InputError(f"max_restarts ({max_restarts}) must be >= 0 and restart_window_s "
                             f"({restart_window_s}) > 0")
        self.respawn = respawn
        self.respawn_delay_s = float(respawn_delay_s)
        self.respawn_max_delay_s = float(respawn_max_delay_s)
        self.max_restarts = int(max_restarts)
        self.restart_window_s = float(restart_window_s)
        self.restarts: dict[str, int] = {}
        self.params_file = Path(params_file)
        if not self.params_file.is_file():
            raise ConfigError(f"{self.params_file}: parameter file not found")
        catalogue = CALIBRATION_NODES if calibrate else NODES
        names = [n.name for n in catalogue]
        chosen = list(nodes) if nodes is not None else names
        unknown = [n for n in chosen if n not in names]
        if unknown:
            raise InputError(f"unknown node(s) {', '.join(unknown)} (known: {', '.join(names)})")
        if not chosen:
            raise InputError("no node to launch")
        self.specs = [s for s in catalogue if s.name in chosen]
        if composed:
            pair = {"detect_triangulate", "hand_eye"}
            if calibrate or not pair <= set(chosen):
                raise InputError("composed: needs both detect_triangulate and hand_eye (not "
                                 "skipped), in localization mode")
            self.specs = [s for s in self.specs if s.name not in pair] + [COMPOSED]
        self.overrides = dict(overrides or {})
        self.root_namespace = root_namespace
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault("PYTHONUNBUFFERED", "1")
        self.env.update(blas_env_defaults(self.env))
        self.out = out or sys.stdout
        self.procs: dict[str, subprocess.Popen[str]] = {}
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()

    def start(self) -> None:
        """Start every node (each in its own process group)."""
        for spec in self.specs:
            self._start_one(spec)

    def _start_one(self, spec: NodeSpec) -> None:
        cmd = node_command(spec, self.params_file, root_namespace=self.root_namespace,
                           overrides=self.overrides.get(spec.name, ()),
                           composed_overrides=self.overrides)
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, env=self.env, start_new_session=True)
        self.procs[spec.name] = proc
        self._say(f"started {spec.name} (pid {proc.pid})")
        th = threading.Thread(target=self._pump, args=(spec.name, proc), daemon=True)
        th.start()
        self._threads.append(th)

    def _say(self, text: str) -> None:
        """A line of the launcher's own, prefixed ``[launch]``."""
        with self._lock:
            self.out.write(f"[launch] {text}\n")
            self.out.flush()

    def _pump(self, name: str, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            with self._lock:
                self.out.write(f"[{name}] {line}")
                self.out.flush()

    def signal_all(self, sig: int = signal.SIGINT) -> None:
        """Send ``sig`` to every child still running."""
        for proc in self.procs.values():
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, sig)
                except ProcessLookupError:
                    pass

    def stop(self, timeout_s: float = 10.0) -> dict[str, int]:
        """SIGINT every child, then SIGKILL what is left after ``timeout_s``; exit codes."""
        self.signal_all(signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for proc in self.procs.values():
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        for th in self._threads:
            th.join(timeout=2.0)
        return {name: proc.returncode for name, proc in self.procs.items()}

    def _supervise(self, stop: threading.Event, end: float | None) -> tuple[str, int] | None:
        """Watch the children until ``stop``, ``end`` or a node given up (returned)."""
        history: dict[str, deque[float]] = {s.name: deque() for s in self.specs}
        due: dict[str, float] = {}
        specs = {s.name: s for s in self.specs}
        while not stop.is_set():
            now = time.monotonic()
            if end is not None and now >= end:
                return None
            for name, proc in self.procs.items():
                code = proc.poll()
                if code is None or name in due:
                    continue
                if not self.respawn:
                    return name, code
                recent = history[name]
                while recent and now - recent[0] > self.restart_window_s:
                    recent.popleft()
                if len(recent) >= self.max_restarts:
                    return name, code
                delay = min(self.respawn_max_delay_s,
                            self.respawn_delay_s * 2 ** len(recent))
                self._say(f"{name} exited with code {code}; restarting in {delay:.1f} s "
                          f"(restart {len(recent) + 1} of at most {self.max_restarts} within "
                          f"{self.restart_window_s:g} s)")
                due[name] = now + delay
            for name, when in list(due.items()):
                if now >= when and not stop.is_set():
                    del due[name]
                    history[name].append(time.monotonic())
                    self.restarts[name] = self.restarts.get(name, 0) + 1
                    self._start_one(specs[name])
            stop.wait(0.05)
        return None

    def first_exited(self) -> tuple[str, int] | None:
        """The first child that has exited, with its code, or None."""
        for name, proc in self.procs.items():
            code = proc.poll()
            if code is not None:
                return name, code
        return None

    def run(self, duration_s: float | None = None) -> int:
        """Start, wait for Ctrl-C/SIGTERM, ``duration_s``, or a child's exit; stop; exit code.

        Returns:
            0 after Ctrl-C, SIGTERM or the duration with every child stopping cleanly; 1 when a
            child exited on its own or failed to stop cleanly.
        """
        stop = threading.Event()
        previous = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
        self.start()
        died = None
        end = None if duration_s is None else time.monotonic() + duration_s
        try:
            died = self._supervise(stop, end)
        finally:
            codes = self.stop()
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        if died is not None:
            name, code = died
            why = (f" ({self.max_restarts} restart(s) within {self.restart_window_s:g} s "
                   "already): giving up" if self.respawn else "")
            print(f"eye-in-hand launch: {name} exited with code {code}{why}; stopped the "
                  "others", file=sys.stderr)
            return 1
        bad = {n: c for n, c in codes.items() if c not in (0, -signal.SIGINT, 130)}
        if bad:
            print("eye-in-hand launch: did not stop cleanly: " + ", ".join(
                f"{n} (code {c})" for n, c in bad.items()), file=sys.stderr)
            return 1
        return 0
