"""End-to-end localization figures (issue: live localization, offline processing).

Prints, using only calibrations the package computes itself from a simulated calibration bag:

* accuracy: base-frame RMS / p95 / max error of the target against ground truth on a
  localization bag (1280x720, 30 Hz, sensor noise 1 grey level, 0.3-0.6 m range), offline and
  live, and the largest live-vs-offline difference over the frames both produced;
* speed of offline processing against the bag's duration (x real time): ``process_bag`` (best
  of three) on the zstd-chunk bag as the simulator writes it and on an uncompressed copy
  (``ros2 bag record``'s default), and the whole ``eye-in-hand process`` command (interpreter
  start-up, imports and output files included) on both; the CPU-seconds each costs per second
  of bag (main process and worker processes), and zstd decompression's alone;
* live over DDS (``detect_triangulate`` and ``hand_eye`` as separate processes, fed at 30 Hz by a
  replayer process that shifts every header stamp to the present): image stamp -> target/pose
  latency p50 / p95, and frames lost (published pairs without a target/pose, and the
  detector's drop-oldest count).

* consistency of the reported covariance (``target/pose_cov``, ``process`` output): NEES (mean
  squared Mahalanobis error of the base-frame point; consistent: within [0.5, 2] x 3 = [1.5, 6])
  and the share of frames inside the 95 % ellipsoid (chi-square, 3 dof), with the simulator's
  robot error off (``--robot-error 0``) and at the realistic default, each with its own
  calibration bag and calibrations; and the base-frame error at the realistic default, next to
  the mean reported sigma. Robot pose sigmas as ``process`` chooses them
  (``core.localization.robot_pose_sigmas``: the arm's stated accuracy from
  ``config/eye_in_hand.yaml``, 0 for the ideal arm, raised by hand_eye.yaml's estimate).

The world is the simulator's default, robot error included (``World.default()``).

Usage: .venv/bin/python benchmarks/bench_localization.py [--pairs N (600: a 20 s bag)] [--fresh]
       .venv/bin/python benchmarks/bench_localization.py --process-only [--trials N]
           [--compare-paths]
(--process-only: the accuracy and speed of offline processing only, both bags in one run, with
the CPU-seconds per second of bag of each and of zstd decompression alone: what two cores
allow at most.)
       .venv/bin/python benchmarks/bench_localization.py --consistency-only [--nees-pairs N]
       .venv/bin/python benchmarks/bench_localization.py --live-only [--live-runs N]
           [--live-mode separate|composed|both] [--nodes-from OTHER_CHECKOUT]
(--live-only: only the live part over DDS, N runs one after the other (default 1), each with
its latency, frames and base-frame error and each node process's CPU per pair: about 40 s a
run; with separate processes, detect_triangulate's CPU per pair against its floor measured
in this process just before and just after the run (``detection_floor``: the conversion of
both images and the locator on the bag's pairs at 30 Hz, about 11 s each; the ratio to their
mean, target <= 1.3x); --live-mode composed runs detect_triangulate + hand_eye in one
process (launch --composed), both alternates the two layouts in each round. The nodes come from the
``eye_in_hand`` package Python imports, so ``PYTHONPATH=<other checkout>`` measures that
checkout's nodes with this script and data, as long as it has this script's imports;
--nodes-from OTHER_CHECKOUT runs, after each round, a separate-process run of that
checkout's nodes (its ``eye-in-hand launch``) fed and measured by this checkout's script: the
first release, ``git worktree add /tmp/first 88607dc``, is the named baseline of the live
figures.)
Data is cached in build/bench-data/ (regenerate with --fresh).
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "build" / "bench-data"
LEFT, RIGHT, POSE = "/stereo/left/image_raw", "/stereo/right/image_raw", "/ee_pose"


def _cli(*args: str, env: dict[str, str] | None = None) -> str:
    proc = subprocess.run([sys.executable, "-m", "eye_in_hand.cli", *args], env=env, text=True,
                          capture_output=True)
    if proc.returncode != 0:
        raise SystemExit(f"failed: eye-in-hand {' '.join(args)}\n{proc.stdout}{proc.stderr}")
    return proc.stdout


def make_data(pairs: int, fresh: bool) -> dict[str, Path]:
    from eye_in_hand.io.bags import BagWriter, bag_info, iter_messages
    from eye_in_hand.sim import World
    from eye_in_hand.sim.output import write_bag

    d = DATA / f"loc{pairs}"
    if fresh and d.exists():
        shutil.rmtree(d)
    paths = {"cal": d / "calibration", "loc": d / "localization", "raw": d / "localization_raw",
             "calib": d / "calib", "he": d / "hand_eye"}
    world = World.default()
    if not paths["cal"].exists():
        print("rendering the calibration bag (15 stops, noise 1) ...", flush=True)
        write_bag(world, paths["cal"], scenario="calibration", frames=15, seed=11,
                  hold_frames=2, still_images_only=True)
    if not paths["loc"].exists():
        print(f"rendering the localization bag ({pairs} pairs, noise 1) ...", flush=True)
        write_bag(world, paths["loc"], scenario="localization", frames=pairs, seed=12)
    if not paths["raw"].exists():
        info = bag_info(paths["loc"])
        with BagWriter(paths["raw"], storage="mcap") as w:
            for name, t in info.topics.items():
                w.add_topic(name, t.msgtype)
            for topic, _mt, stamp, raw in iter_messages(paths["loc"]):
                w.write(topic, stamp, raw)
    if not (paths["calib"] / "left.yaml").exists():
        print("calibrating stereo and hand-eye from the calibration bag ...", flush=True)
        _cli("calibrate", "stereo", "--bag", str(paths["cal"]), "--left-topic", LEFT,
             "--right-topic", RIGHT, "--board", "chessboard:9x6:0.025", "-o",
             str(paths["calib"]))
    if not (paths["he"] / "hand_eye.yaml").exists():
        _cli("calibrate", "handeye", "--bag", str(paths["cal"]), "--board",
             "chessboard:9x6:0.025", "--calibration", str(paths["calib"]), "--left-topic", LEFT,
             "--right-topic", RIGHT, "-o", str(paths["he"]))
    return paths


def params_file(paths: dict[str, Path]) -> Path:
    """config/eye_in_hand.yaml with this run's calibration files: used live and offline."""
    params = paths["calib"].parent / "params.yaml"
    base = (ROOT / "config" / "eye_in_hand.yaml").read_text()
    # written aside and renamed: the cache's files may be hard links shared with other
    # checkouts, and a write in place would change theirs
    tmp = params.with_name(f"params.{os.getpid()}.yaml")
    tmp.write_text(base.replace('calibration_dir: ""          # empty = use the camera_info '
                                   'topics', f'calibration_dir: "{paths["calib"]}"')
                      .replace("hand_eye_file: hand_eye.yaml",
                               f"hand_eye_file: {paths['he'] / 'hand_eye.yaml'}"))
    tmp.replace(params)
    return params


def truth_of(bag: Path) -> tuple[dict[int, np.ndarray], np.ndarray]:
    from eye_in_hand.io.bags import deserialize, iter_messages
    from eye_in_hand.ros.geometry import point_to_xyz, transform_to_matrix
    from eye_in_hand.ros.stamps import header_stamp_ns

    targets: dict[int, np.ndarray] = {}
    X = np.eye(4)
    for topic, mt, _t, raw in iter_messages(bag, ["/ground_truth/target",
                                                  "/ground_truth/hand_eye"]):
        msg = deserialize(raw, mt)
        if topic == "/ground_truth/target":
            targets.setdefault(header_stamp_ns(msg), point_to_xyz(msg.point))
        else:
            X = transform_to_matrix(msg.transform)
    return targets, X


def errors_mm(points: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> str:
    e = np.array([np.linalg.norm(p - truth[s]) for s, p in points.items() if s in truth]) * 1e3
    if e.size == 0:
        return "no frames"
    return (f"RMS {np.sqrt(np.mean(e ** 2)):.3f} mm, p95 {np.percentile(e, 95):.3f} mm, "
            f"max {e.max():.3f} mm ({e.size} frames)")


def offline(paths: dict[str, Path], trials: int = 3
            ) -> tuple[dict[int, np.ndarray], dict[str, float]]:
    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.locator_params import load_locator_config
    from eye_in_hand.io.config import load_hand_eye
    from eye_in_hand.offline import process_bag

    he = load_hand_eye(paths["he"] / "hand_eye.yaml")
    rig = StereoRig.load(paths["calib"])
    cfg = load_locator_config(params_file(paths))   # the live nodes' parameter file
    speeds: dict[str, float] = {}
    points: dict[int, np.ndarray] = {}
    for key in ("loc", "raw"):
        best = None
        for _ in range(trials):
            cpu0 = _cpu_s()
            t0 = time.perf_counter()
            res = process_bag(paths[key], hand_eye_T=he.transform, hand_eye_cov=he.covariance,
                              locator_config=cfg, rig=rig)
            wall = time.perf_counter() - t0
            cpu1 = _cpu_s()
            if best is None or wall < best:     # CPU-seconds of the best run, per bag-second
                speeds[key + "_cpu_main"] = (cpu1[0] - cpu0[0]) / res.duration_s
                speeds[key + "_cpu_workers"] = (cpu1[1] - cpu0[1]) / res.duration_s
            best = wall if best is None else min(best, wall)
        speeds[key] = res.duration_s / best
        speeds[key + "_pairs_per_s"] = res.counts["pairs"] / best
        speeds[key + "_in_processes"] = res.located_in_processes / max(1, res.counts["pairs"])
        if key == "loc":
            points = {f.stamp_ns: f.point_base for f in res.frames if f.point_base is not None}
        duration = res.duration_s
    speeds["zstd_gb_per_cpu_s"], speeds["zstd_cpu_per_bag_s"] = decompression_cpu(paths["loc"],
                                                                                 duration)
    # the whole command, as a user runs it: interpreter start-up, imports, outputs included
    out = paths["calib"].parent / "process-out"
    for key in ("raw", "loc"):
        shutil.rmtree(out, ignore_errors=True)
        t0 = time.perf_counter()
        _cli("process", str(paths[key]), "--calibration", str(paths["calib"]), "--hand-eye",
             str(paths["he"] / "hand_eye.yaml"), "--params", str(params_file(paths)), "-o",
             str(out), "--quiet")
        speeds["cli_" + key] = duration / (time.perf_counter() - t0)
    shutil.rmtree(out, ignore_errors=True)
    return points, speeds


def _cpu_s() -> tuple[float, float]:
    """CPU seconds (user + system) of this process and of its finished children (the worker
    processes, once a run has closed them)."""
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(
        resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime, kids.ru_utime + kids.ru_stime


def decompression_cpu(bag: Path, duration_s: float) -> tuple[float, float]:
    """(GB of output per CPU-second, CPU-seconds per second of bag) of decompressing every
    chunk of ``bag`` in this process, as the workers do (best of two passes)."""
    import mmap

    from eye_in_hand.io.bags.mcap_chunks import _Chunk
    from eye_in_hand.io.bags.reading import _OpenBag

    with _OpenBag(bag) as opened:
        storage = opened.readers[0].storage
        storage = storage.storages[0] if hasattr(storage, "storages") else storage
        with open(storage.path, "rb") as fh:
            view = memoryview(mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ))
        chunks = [_Chunk(c, view) for c in storage.chunks]
        total = sum(c.size for c in chunks)
        best = None
        for _ in range(2):
            t0 = time.process_time()
            for c in chunks:
                c.records(False)
            cpu = time.process_time() - t0
            best = cpu if best is None else min(best, cpu)
    assert best is not None
    return total / best / 1e9, best / duration_s


def compare_paths(paths: dict[str, Path], rounds: int = 2) -> None:
    """The zstd-chunk bag read by worker processes (what ``process`` does) against the thread
    path used before (chunks decompressed on threads of the main process, pairs located on
    threads there), alternating, so that both see the same machine load."""
    import eye_in_hand.io.bags.streams as streams
    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.locator_params import load_locator_config
    from eye_in_hand.io.config import load_hand_eye
    from eye_in_hand.offline import process_bag

    he = load_hand_eye(paths["he"] / "hand_eye.yaml")
    rig = StereoRig.load(paths["calib"])
    cfg = load_locator_config(params_file(paths))
    real = streams.worker_readable
    try:
        for _ in range(rounds):
            for name, readable in (("chunks opened by worker processes", real),
                                   ("threads (the path before)", lambda _p: False)):
                streams.worker_readable = readable  # type: ignore[assignment]
                cpu0, t0 = _cpu_s(), time.perf_counter()
                res = process_bag(paths["loc"], hand_eye_T=he.transform,
                                  hand_eye_cov=he.covariance, locator_config=cfg, rig=rig)
                wall, cpu1 = time.perf_counter() - t0, _cpu_s()
                cpu = (cpu1[0] - cpu0[0] + cpu1[1] - cpu0[1]) / res.duration_s
                print(f"zstd-chunk bag, {name}: {res.duration_s / wall:.2f}x real time, "
                      f"{cpu:.3f} CPU-s per second of bag", flush=True)
    finally:
        streams.worker_readable = real


def print_speeds(speeds: dict[str, float], n: int) -> None:
    """The offline speed lines (both bags, one run)."""
    print(f"offline speed (process_bag, {n / 30:.0f} s bag): {speeds['raw']:.1f}x real time on "
          f"the uncompressed bag ({speeds['raw_pairs_per_s']:.0f} pairs/s, "
          f"{100 * speeds['raw_in_processes']:.0f}% of pairs in worker processes), "
          f"{speeds['loc']:.1f}x on the zstd-chunk bag ({speeds['loc_pairs_per_s']:.0f} pairs/s, "
          f"{100 * speeds['loc_in_processes']:.0f}% of pairs in worker processes, "
          f"zstd by {zstd_binding()})  (targets: >= 10x uncompressed, >= 8x zstd)")
    print(f"zstd decompression alone (this process, every chunk of the zstd-chunk bag): "
          f"{speeds['zstd_gb_per_cpu_s']:.2f} GB of output per CPU-second, "
          f"{speeds['zstd_cpu_per_bag_s']:.3f} CPU-s per second of bag")
    for key, name in (("raw", "uncompressed"), ("loc", "zstd-chunk")):
        main, workers = speeds[key + "_cpu_main"], speeds[key + "_cpu_workers"]
        print(f"CPU per second of bag ({name}, best run): {main:.3f} s in the main process + "
              f"{workers:.3f} s in the workers = {main + workers:.3f} s: at most "
              f"{2 / (main + workers):.1f}x real time on 2 otherwise idle cores")
    print(f"offline speed (`eye-in-hand process` command, start-up and outputs included): "
          f"{speeds['cli_raw']:.1f}x real time on the uncompressed bag, {speeds['cli_loc']:.1f}x "
          "on the zstd-chunk bag", flush=True)


def bag_consistency(paths: dict[str, Path]) -> dict[str, float]:
    """NEES, 95 % coverage and mean sigma of ``target/pose_cov`` over this run's localization
    bag, robot pose sigmas as ``process`` chooses them; and with hand_eye.yaml's estimate alone
    (the arm's stated accuracy set to 0) for comparison."""
    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.localization import robot_pose_sigmas
    from eye_in_hand.core.locator_params import load_locator_config, load_parameter_file
    from eye_in_hand.io.config import load_hand_eye
    from eye_in_hand.offline import ProcessOptions, process_bag

    he = load_hand_eye(paths["he"] / "hand_eye.yaml")
    he_params = load_parameter_file(ROOT / "config" / "eye_in_hand.yaml", "hand_eye")
    truth, _ = truth_of(paths["loc"])
    out: dict[str, float] = {}
    stated = (float(he_params.get("robot_sigma_pos_m", ProcessOptions.robot_sigma_pos_m)),
              float(he_params.get("robot_sigma_rot_rad", ProcessOptions.robot_sigma_rot_rad)))
    for tag, st in (("", stated), ("estimate_only_", (0.0, 0.0))):
        sig = robot_pose_sigmas(*st, he.robot_pose_noise)
        res = process_bag(paths["raw"], hand_eye_T=he.transform, hand_eye_cov=he.covariance,
                          locator_config=load_locator_config(params_file(paths)),
                          rig=StereoRig.load(paths["calib"]),
                          options=ProcessOptions(robot_sigma_pos_m=sig[0],
                                                 robot_sigma_rot_rad=sig[1]))
        m2, err, tr = [], [], []
        for f in res.frames:
            if f.point_base is None or f.cov_base is None or f.stamp_ns not in truth:
                continue
            e = f.point_base - truth[f.stamp_ns]
            m2.append(float(e @ np.linalg.solve(f.cov_base, e)))
            err.append(float(e @ e))
            tr.append(float(np.sqrt(np.trace(f.cov_base))))
        a = np.asarray(m2)
        out.update({tag + "nees": float(a.mean()), tag + "coverage95": float(np.mean(a <= 7.8147)),
                    tag + "rms_mm": 1e3 * float(np.sqrt(np.mean(err))),
                    tag + "sigma_mm": 1e3 * float(np.mean(tr)), tag + "frames": float(a.size),
                    tag + "robot_sigma_pos_mm": 1e3 * sig[0],
                    tag + "robot_sigma_rot_mrad": 1e3 * sig[1]})
    return out


def zstd_binding() -> str:
    """The module that decompresses zstd chunks (eye_in_hand.io.bags.mcap_chunks picks it)."""
    from eye_in_hand.io.bags import mcap_chunks

    return mcap_chunks.zstd_binding()


# -- live -----------------------------------------------------------------------------------
def replay(bag: str, lead_s: float) -> None:
    """Child process: publish the bag's images and poses at recorded pace, stamps shifted to now.

    Prints the stamp offset (ns) on its first line so the parent can map stamps back.
    """
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from eye_in_hand.io.bags import iter_messages
    from eye_in_hand.ros.dds import use_large_data_profile

    use_large_data_profile()
    msgs = [(t, topic, bytearray(raw)) for topic, _mt, t, raw in
            iter_messages(bag, [LEFT, RIGHT, POSE])]
    rclpy.init()
    node = Node("bench_replayer")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {LEFT: node.create_publisher(Image, LEFT, qos),
            RIGHT: node.create_publisher(Image, RIGHT, qos),
            POSE: node.create_publisher(PoseStamped, POSE, qos)}
    deadline = time.monotonic() + 30
    while any(p.get_subscription_count() == 0 for p in pubs.values()) and \
            time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)  # let discovery settle in both directions
    t_first = msgs[0][0]
    offset = time.time_ns() + int(lead_s * 1e9) - t_first
    print(offset, flush=True)
    start_mono = time.monotonic_ns() + int(lead_s * 1e9)
    for t, topic, raw in msgs:
        sec, nsec = divmod(struct.unpack_from("<iI", raw, 4)[0] * 1_000_000_000
                           + struct.unpack_from("<iI", raw, 4)[1] + offset, 1_000_000_000)
        struct.pack_into("<iI", raw, 4, sec, nsec)   # CDR LE: header.stamp right after 4 bytes
        due = start_mono + (t - t_first)
        delay = (due - time.monotonic_ns()) / 1e9
        if delay > 0:
            time.sleep(delay)
        pubs[topic].publish(bytes(raw))
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()


def _node_pids(launcher_pid: int) -> dict[str, str]:
    """The node processes the launcher started: node name (the ``eye_in_hand.nodes.<name>``
    module it runs; else its pid) -> pid (Linux /proc; empty elsewhere)."""
    try:
        kids = Path(f"/proc/{launcher_pid}/task/{launcher_pid}/children").read_text().split()
    except OSError:
        return {}
    out: dict[str, str] = {}
    for pid in kids:
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        module = next((c.decode() for c in cmd if c.startswith(b"eye_in_hand.nodes.")), pid)
        out[module.rsplit(".", 1)[-1]] = pid
    return out


def node_cpu_s(launcher_pid: int) -> dict[str, float]:
    """CPU seconds (user + system) so far of each node process the launcher started, by node
    name (Linux /proc; empty elsewhere)."""
    out: dict[str, float] = {}
    tick = os.sysconf("SC_CLK_TCK")
    for name, pid in _node_pids(launcher_pid).items():
        try:
            stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[name] = (int(stat[11]) + int(stat[12])) / tick
    return out


def node_threads(launcher_pid: int) -> dict[str, dict[str, tuple[float, int]]]:
    """Per node process the launcher started: CPU seconds and minor page faults so far of its
    threads, grouped as ``main`` (the interpreter's main thread: a node's executor; in the
    composed process ``hand_eye``'s), by OS name for the threads the package names
    (``detect_worker``: ``detect_triangulate``'s worker; ``detect_exec``: its executor in the
    composed process; eye_in_hand.threads.name_os_thread), ``python`` for other Python
    threads, and Fast DDS's by kind (``dds.shm``, ``dds.ev``, ...; Linux /proc, empty
    elsewhere)."""
    out: dict[str, dict[str, tuple[float, int]]] = {}
    tick = os.sysconf("SC_CLK_TCK")
    for name, pid in _node_pids(launcher_pid).items():
        try:
            tasks = list(Path(f"/proc/{pid}/task").iterdir())
        except OSError:
            continue
        groups: dict[str, tuple[float, int]] = {}
        for task in tasks:
            try:
                comm = (task / "comm").read_text().strip()
                stat = (task / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            label = "main" if task.name == pid else re.sub(r"[.\d]+$", "", comm) or comm
            cpu, faults = groups.get(label, (0.0, 0))
            groups[label] = (cpu + (int(stat[11]) + int(stat[12])) / tick,
                             faults + int(stat[7]))
        out[name] = groups
    return out


def spin_in_background(executor: Any) -> Callable[[], None]:
    """Spin ``executor`` on a daemon thread; returns the function that stops and joins it."""
    stop = threading.Event()
    thread = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.05)
                                              for _ in iter(stop.is_set, True)], daemon=True)
    thread.start()

    def halt() -> None:
        stop.set()
        thread.join()

    return halt


def subscribe_outputs(node: Any, qos: Any) -> None:
    """Subscribe ``node`` to every ``hand_eye`` output in :data:`ALL_OUTPUTS` (``/tf`` when
    tf2_msgs is installed: without it hand_eye sends no /tf either)."""
    from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped
    from visualization_msgs.msg import MarkerArray

    types: dict[str, type] = {"PoseStamped": PoseStamped, "PoseArray": PoseArray,
                             "PoseWithCovarianceStamped": PoseWithCovarianceStamped,
                             "MarkerArray": MarkerArray}
    try:
        from tf2_msgs.msg import TFMessage
        types["TFMessage"] = TFMessage
    except ImportError:
        pass
    for name, topic in ALL_OUTPUTS:
        if name in types:
            node.create_subscription(types[name], topic, lambda _m: None, qos)


#: hand_eye's outputs besides target/pose (the bench's target is red): with ``--outputs all``
#: the listener subscribes to every one, as the issue's figure asks (volatile outputs are built
#: and sent only while subscribed; /tf always goes out)
ALL_OUTPUTS = (("PoseWithCovarianceStamped", "/target/pose_cov"),
               ("PoseStamped", "/target/red/pose"),
               ("PoseWithCovarianceStamped", "/target/red/pose_cov"),
               ("PoseArray", "/target/poses"), ("MarkerArray", "/target/markers"),
               ("TFMessage", "/tf"))


def live(paths: dict[str, Path], composed: bool = False, all_outputs: bool = True,
         nodes_from: Path | None = None) -> tuple[dict[int, np.ndarray], dict[str, float]]:
    """One live run (module docs); ``nodes_from``: the nodes of that checkout (its
    ``eye-in-hand launch``, it first on ``PYTHONPATH``), fed and measured by this script."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from eye_in_hand.ros.dds import use_large_data_profile
    from eye_in_hand.ros.qos import RESULT_QOS
    from eye_in_hand.ros.stamps import header_stamp_ns

    env = dict(os.environ)
    # the caller's domain when set (a shared machine), else a random one
    env["ROS_DOMAIN_ID"] = env.get("ROS_DOMAIN_ID") or str(
        random.SystemRandom().randint(120, 200))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    use_large_data_profile(env)
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    use_large_data_profile()
    params = params_file(paths)
    # run in the checkout whose eye_in_hand this script imported: `python -m` puts the working
    # directory first on sys.path, so from another checkout's root its nodes would run instead
    # of the PYTHONPATH one's
    import eye_in_hand
    code_root = Path(eye_in_hand.__file__).resolve().parent.parent
    launch_env = env
    if nodes_from is not None:      # that checkout's nodes; the replay stays this script's
        code_root = nodes_from
        launch_env = {**env, "PYTHONPATH": str(nodes_from)}
    launch = subprocess.Popen([sys.executable, "-m", "eye_in_hand.cli", "launch", "--params",
                               str(params), "--skip", "stereo_capture",
                               *(["--composed"] if composed else [])], env=launch_env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              start_new_session=True, cwd=code_root)
    rclpy.init()
    node = Node("bench_listener")
    received: list[tuple[int, int, np.ndarray]] = []
    diag: dict[str, dict[str, str]] = {}

    def on_pose(msg: PoseStamped) -> None:
        now = time.time_ns()
        p = msg.pose.position
        received.append((header_stamp_ns(msg), now, np.array([p.x, p.y, p.z])))

    def on_diag(msg: DiagnosticArray) -> None:
        for s in msg.status:
            diag[s.name] = {v.key: v.value for v in s.values}

    node.create_subscription(PoseStamped, "/target/pose", on_pose, RESULT_QOS)
    if all_outputs:
        subscribe_outputs(node, RESULT_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    stop_spinning = spin_in_background(ex)
    rep = subprocess.Popen([sys.executable, __file__, "--replay", str(paths["loc"])], env=env,
                           text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    offset = int(rep.stdout.readline().strip() or 0)   # type: ignore[union-attr]
    cpu0 = node_cpu_s(launch.pid)                    # the nodes are up: start-up excluded
    # steady state: the nodes' CPU between the 60th and the 540th pose received (10-90 % of
    # a 600-pair replay), without the replay's lead-in and the idle tail
    steady: list[tuple[int, dict[str, float]]] = []
    threads: list[dict[str, dict[str, tuple[float, int]]]] = []

    def watch() -> None:
        for mark in (60, 540):
            while len(received) < mark and rep.poll() is None:
                time.sleep(0.005)
            if len(received) >= mark:
                steady.append((len(received), node_cpu_s(launch.pid)))
                threads.append(node_threads(launch.pid))

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    rep.wait(timeout=600)
    watcher.join(timeout=5.0)
    time.sleep(3.0)                                  # last results + one diagnostics period
    cpu1 = node_cpu_s(launch.pid)
    stop_spinning()
    import signal as _signal
    os.killpg(launch.pid, _signal.SIGINT)
    launch.communicate(timeout=30)
    node.destroy_node()
    rclpy.shutdown()
    lat = np.array([(now - stamp) / 1e6 for stamp, now, _ in received])
    det = next((v for k, v in diag.items() if "detect_triangulate" in k), {})
    figures = {"received": len(received),
               "p50_ms": float(np.percentile(lat, 50)) if lat.size else float("nan"),
               "p95_ms": float(np.percentile(lat, 95)) if lat.size else float("nan"),
               "max_ms": float(lat.max()) if lat.size else float("nan"),
               "dropped_pairs": float(det.get("dropped_pairs", "nan")),
               "sync_dropped": float(det.get("sync_dropped", "nan")),
               "queue_max": float(det.get("queue_max", "nan"))}
    pairs = float(det.get("pairs", "nan"))
    for name, cpu in cpu1.items():   # CPU per processed pair, replay and idle tail included
        figures[f"cpu_ms_per_pair.{name}"] = (cpu - cpu0.get(name, 0.0)) * 1e3 / pairs
    if len(steady) == 2:
        (n0, c0), (n1, c1) = steady
        for name, cpu in c1.items():
            figures[f"steady_cpu_ms_per_pair.{name}"] = (cpu - c0.get(name, 0.0)) * 1e3 / (n1 - n0)
        for name, groups in threads[1].items():
            for label, (cpu, faults) in groups.items():
                cpu0_, faults0 = threads[0].get(name, {}).get(label, (0.0, 0))
                figures[f"thread_cpu_ms_per_pair.{name}.{label}"] = (cpu - cpu0_) * 1e3 / (n1 - n0)
                figures[f"thread_faults_per_pair.{name}.{label}"] = (faults - faults0) / (n1 - n0)
    return {stamp - offset: p for stamp, _now, p in received}, figures


def detection_floor(paths: dict[str, Path], pairs: int = 300,
                    rate_hz: float = 30.0) -> dict[str, float]:
    """The floor of ``detect_triangulate``'s CPU per pair (issue 24: at most 1.3x the
    detection plus the image conversion), measured in this process on the localization bag's
    own pairs at the camera's cadence (one pair every ``1 / rate_hz`` s, as the node gets
    them; code run after 33 ms idle costs more than back to back): the conversion of both
    ``sensor_msgs/Image`` messages (rclpy's deserialization of the CDR bytes a take returns,
    then ``image_to_numpy``) and ``StereoLocator.locate`` with the node's parameters and
    calibration. CPU of the whole process (OpenCV's threads included), ms per pair, after 10
    pairs of warm-up; run when no node is up."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image

    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.locator import StereoLocator
    from eye_in_hand.core.locator_params import load_locator_config
    from eye_in_hand.io.bags import iter_messages
    from eye_in_hand.ros.images import image_to_numpy

    n = pairs + 10                    # the first 10: warm-up
    sides: dict[str, list[bytes]] = {LEFT: [], RIGHT: []}
    for topic, _mt, _t, raw in iter_messages(paths["loc"], [LEFT, RIGHT]):
        if len(sides[topic]) < n:
            sides[topic].append(bytes(raw))
        elif all(len(v) >= n for v in sides.values()):
            break                     # the images needed, not the bag's 3 GB of them
    todo = list(zip(sides[LEFT][:n], sides[RIGHT][:n], strict=True))
    locator = StereoLocator(StereoRig.load(paths["calib"]),
                            load_locator_config(params_file(paths)))
    conv = det = 0.0
    t_next = time.monotonic()
    for k, (raw_l, raw_r) in enumerate(todo):
        t_next += 1.0 / rate_hz
        delay = t_next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        c0 = time.process_time()
        left = image_to_numpy(deserialize_message(raw_l, Image))
        right = image_to_numpy(deserialize_message(raw_r, Image))
        c1 = time.process_time()
        locator.locate(left, right)
        c2 = time.process_time()
        if k >= 10:
            conv += c1 - c0
            det += c2 - c1
    timed = max(1, len(todo) - 10)
    return {"conversion_ms": conv * 1e3 / timed, "detection_ms": det * 1e3 / timed,
            "pairs": timed}


def print_floor(fig: dict[str, float], floors: list[dict[str, float]]) -> None:
    """detect_triangulate's CPU per pair while streaming against the floor of the same run:
    measured just before and just after the live run (the machine's state moves the floor
    by 10-30 % between minutes), the ratio to their mean."""
    bases = [f["conversion_ms"] + f["detection_ms"] for f in floors]
    parts = "; ".join(f"{when} {f['conversion_ms']:.2f} + {f['detection_ms']:.2f} = {b:.2f} ms"
                      for when, f, b in zip(("before", "after"), floors, bases, strict=True))
    base = sum(bases) / len(bases)
    line = (f"floor (this process, the bag's first {floors[0]['pairs']:.0f} pairs at 30 Hz, "
            f"image conversion + detection per pair): {parts}")
    own = fig.get("steady_cpu_ms_per_pair.detect_triangulate")
    if own is not None:
        line += (f"; detect_triangulate {own:.2f} ms = {own / base:.2f}x their mean "
                 "(target <= 1.3x)")
    print(line, flush=True)


def consistency(pairs: int, fresh: bool) -> dict[str, dict[str, float]]:
    """NEES, 95 % coverage and error of the base-frame point, robot error 0 and default."""
    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.localization import robot_pose_sigmas
    from eye_in_hand.core.locator_params import load_locator_config, load_parameter_file
    from eye_in_hand.io.config import load_hand_eye
    from eye_in_hand.offline import ProcessOptions, process_bag
    from eye_in_hand.sim import World
    from eye_in_hand.sim.output import write_bag
    from eye_in_hand.sim.robot_error import RobotErrorSpec

    chi2_95 = 7.8147  # chi-square, 3 dof, 95 %
    he_params = load_parameter_file(ROOT / "config" / "eye_in_hand.yaml", "hand_eye")
    out: dict[str, dict[str, float]] = {}
    for tag, spec in (("robot error 0", RobotErrorSpec.none()),
                      ("robot error default", RobotErrorSpec.default())):
        d = DATA / f"nees{pairs}-{'ideal' if spec.is_ideal else 'default'}"
        if fresh and d.exists():
            shutil.rmtree(d)
        world = World.default().with_robot_error(spec)
        cal, loc, calib, he_dir = d / "calibration", d / "localization", d / "calib", d / "he"
        for bag, kwargs in ((cal, dict(scenario="calibration", frames=15, seed=21,
                                       hold_frames=2, still_images_only=True)),
                            (loc, dict(scenario="localization", frames=pairs, seed=22))):
            if not bag.exists():   # written aside, then renamed: never a half bag in the cache
                print(f"[{tag}] rendering {bag} ...", flush=True)
                shutil.rmtree(bag.with_name(bag.name + ".part"), ignore_errors=True)
                write_bag(world, bag.with_name(bag.name + ".part"), **kwargs)  # type: ignore
                bag.with_name(bag.name + ".part").rename(bag)
        if not (calib / "left.yaml").exists():
            _cli("calibrate", "stereo", "--bag", str(cal), "--left-topic", LEFT,
                 "--right-topic", RIGHT, "--board", "chessboard:9x6:0.025", "-o", str(calib))
        if not (he_dir / "hand_eye.yaml").exists():
            _cli("calibrate", "handeye", "--bag", str(cal), "--board", "chessboard:9x6:0.025",
                 "--calibration", str(calib), "--left-topic", LEFT, "--right-topic",
                 RIGHT, "--no-html", "-o", str(he_dir))
        he = load_hand_eye(he_dir / "hand_eye.yaml")
        cfg = load_locator_config(ROOT / "config" / "eye_in_hand.yaml")  # radius 35 mm
        # robot pose sigmas as process and the hand_eye node choose them
        # (core.localization.robot_pose_sigmas): the arm's stated accuracy, raised to
        # hand_eye.yaml's estimate where larger. The stated accuracy is the parameter file's
        # (0.15 mm, 0.4 mrad: the default arm's per-axis flange error) for the default arm,
        # and 0 for the ideal arm (its poses are exact: the honest statement there).
        stated = (0.0, 0.0) if spec.is_ideal else (
            float(he_params.get("robot_sigma_pos_m", ProcessOptions.robot_sigma_pos_m)),
            float(he_params.get("robot_sigma_rot_rad", ProcessOptions.robot_sigma_rot_rad)))
        sig = robot_pose_sigmas(*stated, he.robot_pose_noise)
        opts = ProcessOptions(workers=1, robot_sigma_pos_m=sig[0], robot_sigma_rot_rad=sig[1])
        res = process_bag(loc, hand_eye_T=he.transform, hand_eye_cov=he.covariance,
                          locator_config=cfg,
                          rig=StereoRig.load(calib), options=opts)
        truth, _ = truth_of(loc)
        m2, err = [], []
        for f in res.frames:
            if f.point_base is None or f.cov_base is None or f.stamp_ns not in truth:
                continue
            e = f.point_base - truth[f.stamp_ns]
            m2.append(float(e @ np.linalg.solve(f.cov_base, e)))
            err.append(float(np.linalg.norm(e)))
        m2a, erra = np.array(m2), np.array(err) * 1e3
        fig = {"nees": float(m2a.mean()), "coverage95": float(np.mean(m2a <= chi2_95)),
               "rms_mm": float(np.sqrt(np.mean(erra ** 2))),
               "p95_mm": float(np.percentile(erra, 95)), "max_mm": float(erra.max()),
               "frames": float(m2a.size),
               "sigma_mm": float(np.mean([np.sqrt(np.trace(f.cov_base)) for f in res.frames
                                          if f.cov_base is not None])) * 1e3,
               "robot_sigmas": (opts.robot_sigma_pos_m, opts.robot_sigma_rot_rad)}
        print(f"[{tag}] base-frame point over {m2a.size} frames: NEES {fig['nees']:.2f} "
              f"(consistent: 1.5-6), 95 % coverage {100 * fig['coverage95']:.1f} %, error RMS "
              f"{fig['rms_mm']:.3f} mm, p95 {fig['p95_mm']:.3f} mm, max {fig['max_mm']:.3f} mm; "
              f"reported sigma (sqrt trace) mean {fig['sigma_mm']:.3f} mm; robot pose sigmas "
              f"{opts.robot_sigma_pos_m * 1e3:.3g} mm, {opts.robot_sigma_rot_rad * 1e3:.3g} mrad "
              f"(stated {stated[0] * 1e3:.3g} mm, {stated[1] * 1e3:.3g} mrad; hand_eye.yaml "
              + ("none" if he.robot_pose_noise is None else
                 f"{he.robot_pose_noise['translation_sigma_m'] * 1e3:.3g} mm, "
                 f"{he.robot_pose_noise['rotation_sigma_rad'] * 1e3:.3g} mrad") + ")",
              flush=True)
        out[tag] = fig
    return out


def print_live(fig: dict[str, float], live_pts: dict[int, np.ndarray],
               truth: dict[int, np.ndarray]) -> None:
    """The live run's accuracy, latency and frame figures."""
    print(f"live accuracy: {errors_mm(live_pts, truth)}")
    print(f"live latency image stamp -> target/pose: p50 {fig['p50_ms']:.1f} ms, p95 "
          f"{fig['p95_ms']:.1f} ms, max {fig['max_ms']:.1f} ms  (target p95 <= 25 ms)")
    print(f"live frames: {fig['received']}/{len(truth)} poses received; detect_triangulate "
          f"dropped {fig['dropped_pairs']:.0f} pairs to backlog (at most "
          f"{fig['queue_max']:.0f} pairs waited), {fig['sync_dropped']:.0f} frames unpaired  "
          "(target: 0 lost to backlog)")
    cpu = {k.split(".", 1)[1]: v for k, v in fig.items() if k.startswith("cpu_ms_per_pair.")}
    print("live CPU per processed pair: " + ", ".join(f"{k} {v:.1f} ms" for k, v in
                                                      sorted(cpu.items()))
          + f"; all nodes {sum(cpu.values()):.1f} ms (replay and 3 s idle tail included)",
          flush=True)
    steady = {k.split(".", 1)[1]: v for k, v in fig.items()
              if k.startswith("steady_cpu_ms_per_pair.")}
    if steady:
        print("live CPU per pair while streaming (poses 60-540): " + ", ".join(
            f"{k} {v:.2f} ms" for k, v in sorted(steady.items()))
            + f"; all nodes {sum(steady.values()):.2f} ms", flush=True)
    for name in sorted(steady):
        key = f"thread_cpu_ms_per_pair.{name}."
        parts = sorted(((k[len(key):], v) for k, v in fig.items() if k.startswith(key)),
                       key=lambda kv: -kv[1])
        print(f"  {name} by thread (CPU ms / minor page faults per pair): " + ", ".join(
            f"{label} {v:.2f} / {fig[f'thread_faults_per_pair.{name}.{label}']:.1f}"
            for label, v in parts if v >= 0.005), flush=True)
    composed_he = fig.get("thread_cpu_ms_per_pair.localize.main")
    if composed_he is not None:
        dds = sum(v for k, v in fig.items()
                  if k.startswith("thread_cpu_ms_per_pair.localize.dds"))
        print(f"  hand_eye in the composed process: {composed_he:.2f} ms per pair on its "
              "executor thread (target <= 1.5 ms); the process's Fast DDS threads "
              f"({dds:.2f} ms, mostly the images) serve both nodes", flush=True)


def checkout_commit(code: Path) -> str:
    """The checkout's commit (short), or ``unknown commit``."""
    try:
        return subprocess.run(["git", "-C", str(code), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown commit"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pairs", type=int, default=600, help="localization pairs (30 Hz)")
    parser.add_argument("--fresh", action="store_true", help="regenerate the cached data")
    parser.add_argument("--replay", metavar="BAG", help=argparse.SUPPRESS)
    parser.add_argument("--nees-pairs", type=int, default=90,
                        help="localization pairs of the consistency part (default 90)")
    parser.add_argument("--consistency-only", action="store_true",
                        help="only the covariance consistency (NEES) part")
    parser.add_argument("--process-only", action="store_true",
                        help="only the offline accuracy and speed part (both bags, one run)")
    parser.add_argument("--compare-paths", action="store_true",
                        help="also the zstd bag through worker processes against the thread "
                             "path used before, alternating (two rounds)")
    parser.add_argument("--live-only", action="store_true",
                        help="only the live part over DDS (latency, frames, error)")
    parser.add_argument("--live-runs", type=int, default=1,
                        help="live runs of --live-only, one after the other (default 1)")
    parser.add_argument("--live-mode", choices=("separate", "composed", "both"),
                        default="separate",
                        help="--live-only: detect_triangulate and hand_eye as separate "
                             "processes (eye-in-hand launch), in one (launch --composed), or "
                             "both alternating, each --live-runs times (default separate)")
    parser.add_argument("--nodes-from", metavar="OTHER_CHECKOUT", type=Path,
                        help="--live-only: also, after each round, a separate-process run of "
                             "OTHER_CHECKOUT's nodes (its eye-in-hand launch) on the same bag, "
                             "e.g. the first release: git worktree add /tmp/first 88607dc")
    parser.add_argument("--outputs", choices=("all", "pose"), default="all",
                        help="live: the listener subscribes to every hand_eye output (all, "
                             "default) or to target/pose alone (pose; the figures before "
                             "2026-11-28 were taken so)")
    parser.add_argument("--trials", type=int, default=3,
                        help="process_bag runs per bag, the best one counts (default 3)")
    args = parser.parse_args()
    if args.nodes_from is not None and not args.live_only:
        parser.error("--nodes-from: only with --live-only")
    if args.nodes_from is not None and not (args.nodes_from / "eye_in_hand").is_dir():
        parser.error(f"--nodes-from {args.nodes_from}: not a checkout of this package (no "
                     "eye_in_hand/ in it); make one with git worktree add DIR COMMIT")
    if args.replay:
        replay(args.replay, lead_s=0.5)
        return 0
    if args.consistency_only:
        consistency(args.nees_pairs, args.fresh)
        return 0
    paths = make_data(args.pairs, args.fresh)
    truth, X_true = truth_of(paths["loc"])
    if args.live_only:
        import eye_in_hand

        print(f"nodes from {Path(eye_in_hand.__file__).parent}; the listener subscribes to "
              + ("every hand_eye output" if args.outputs == "all" else "target/pose alone"))
        modes = ["separate", "composed"] if args.live_mode == "both" else [args.live_mode]
        for _ in range(args.live_runs):
            for mode in modes:
                print(f"== live, {mode} processes" if mode == "separate" else
                      "== live, composed (detect_triangulate + hand_eye in one process)")
                before = detection_floor(paths) if mode == "separate" else None
                live_pts, fig = live(paths, composed=mode == "composed",
                                     all_outputs=args.outputs == "all")
                print_live(fig, live_pts, truth)
                if before is not None:
                    print_floor(fig, [before, detection_floor(paths)])
            if args.nodes_from is not None:
                other = args.nodes_from.resolve()
                print(f"== live, separate processes, the nodes of {other} "
                      f"({checkout_commit(other)})")
                live_pts, fig = live(paths, all_outputs=args.outputs == "all",
                                     nodes_from=other)
                print_live(fig, live_pts, truth)
        return 0
    from eye_in_hand.core.camera import StereoRig
    from eye_in_hand.core.transforms import transform_distance
    from eye_in_hand.io.config import load_hand_eye

    he = load_hand_eye(paths["he"] / "hand_eye.yaml")
    dt, dr = transform_distance(he.transform, X_true)
    rig = StereoRig.load(paths["calib"])
    print(f"\ncalibrations computed by the package: baseline {1000 * rig.baseline:.3f} mm; "
          f"hand-eye {1000 * dt:.3f} mm / {np.degrees(dr):.4f} deg from the true mount")
    off_pts, speeds = offline(paths, args.trials)
    n = len(truth)
    print(f"offline accuracy ({n} pairs, 1280x720, noise 1): {errors_mm(off_pts, truth)}  "
          "(target RMS <= 2 mm)")
    print_speeds(speeds, n)
    if args.compare_paths:
        compare_paths(paths)
    if args.process_only:
        return 0
    bc = bag_consistency(paths)
    print(f"target/pose_cov on this bag ({bc['frames']:.0f} frames, robot pose sigmas "
          f"{bc['robot_sigma_pos_mm']:.3g} mm, {bc['robot_sigma_rot_mrad']:.3g} mrad): NEES "
          f"{bc['nees']:.2f} (consistent: 1.5-6), 95 % coverage {100 * bc['coverage95']:.1f} %, "
          f"mean sigma (sqrt trace) {bc['sigma_mm']:.3f} mm against RMS error "
          f"{bc['rms_mm']:.3f} mm; with hand_eye.yaml's estimate alone "
          f"({bc['estimate_only_robot_sigma_pos_mm']:.3g} mm, "
          f"{bc['estimate_only_robot_sigma_rot_mrad']:.3g} mrad): NEES "
          f"{bc['estimate_only_nees']:.2f}, coverage {100 * bc['estimate_only_coverage95']:.1f} %")
    before = detection_floor(paths)
    live_pts, fig = live(paths, all_outputs=args.outputs == "all")
    common = sorted(set(live_pts) & set(off_pts))
    diff = max((float(np.max(np.abs(live_pts[s] - off_pts[s]))) for s in common),
               default=float("nan"))
    print(f"live vs offline: {len(common)} frames in both, largest difference {diff:.2e} m  "
          "(target <= 1e-6 m)")
    print_live(fig, live_pts, truth)
    print_floor(fig, [before, detection_floor(paths)])
    nees = consistency(args.nees_pairs, args.fresh)
    (DATA / "bench_localization.json").write_text(json.dumps(
        {"speeds": speeds, "live": fig, "live_vs_offline_m": diff, "consistency": nees,
         "bag_consistency": bc},
        indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
