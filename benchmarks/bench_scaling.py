"""How the whole ``eye-in-hand process`` command scales: time and memory against bag length,
number of targets and image size, each point next to its floor measured in the same run.

Curves (each point one ``eye-in-hand process`` run, a subprocess, start-up included):

* bag length 20 s, 2 min, 10 min (640x480, 1 target);
* number of targets 1, 4, 8 (20 s, 640x480; one colour each, so pairs go to worker processes);
* image size 640x480, 1280x720, 1920x1080 (20 s, 1 target).

Per point: wall time, CPU of the whole process tree (``getrusage(RUSAGE_CHILDREN)`` after it exits:
the command and its worker processes), CPU/wall, the peak RSS of the tree (the sum over its
processes, sampled from ``/proc`` at about 20 Hz; also its anonymous part, ``RssAnon``, without the
bag's file pages), its peak proportional set size (PSS, from ``smaps_rollup`` at about 4 Hz: the
memory the tree really holds, where the RSS sum counts pages a forked worker shares with the
reading process once per process), the peak PSS in each quarter of the run's wall time (flat from
the second quarter on when nothing is held per pair; the first holds the start-up, the last of a
short run the output files after the workers exited) and the peak RSS of its largest single process
(``VmHWM``), and the **floor**: the CPU of reading every image's bytes from the same bag
(decompressing its chunks) and ``cvtColor(BGR2HSV)`` + one ``inRange`` per target of both images of
every pair, in one thread of this process, on the same bag in the same run (with ``--repeat N``:
the least CPU of N runs of the command, and of N measurements of the floor, one after each run).
Per curve, the least-squares slope of wall, CPU, floor CPU and peak memory against the curve's
variable, with R^2 (1 = a straight line).

The bags: a few seconds of distinct stereo pairs are rendered with the simulator (no sensor
noise, as the bundled bags: a 10-minute 640x480 bag is about 1 GB with zstd chunks instead of 33
GB raw) and cycled, with new stamps (header and log time) and the matching robot poses
(``/ee_pose``, 125 Hz), ground truth and camera_info, to the length wanted, through
:class:`eye_in_hand.io.bags.BagWriter` with zstd chunks (``--storage none``: uncompressed, what
``ros2 bag record`` writes by default; a 10-minute 640x480 bag is then 33 GB). Cached in
``build/bench-data/scaling/``. The hand-eye file is the true mount; the rig comes from the bag's
camera_info.

Usage: .venv/bin/python benchmarks/bench_scaling.py [--quick] [--storage zstd|none]
           [--curves length,targets,size] [--repeat N] [--fresh]
           [--compare OTHER_CHECKOUT] [--prepare]
(--compare: OTHER_CHECKOUT's process on the same bags, runs alternating (any release's: the
first release, ``git worktree add /tmp/first 88607dc``, is the named baseline); --prepare:
only the bags.
--quick: 5 s / 10 s / 20 s bags, 320x240 / 640x480 / 960x540: a few minutes.)
       .venv/bin/python benchmarks/bench_scaling.py --startup [longest] [--compare OTHER]
           [--repeat N]
(--startup: the CPU of each phase of `process` on the shortest bag of the chosen curves, or
the longest: interpreter and imports, the --params key check, the rig, the pass over the bag
with its worker processes, the ground-truth matching, the output files; and the wall time from
the launch to the first task handed to a worker process, to the end of the pass and to the
exit.)
       .venv/bin/python benchmarks/bench_scaling.py --identity OTHER_CHECKOUT
(--identity: runs ``eye-in-hand process`` of this checkout and of OTHER_CHECKOUT (its
``eye_in_hand`` first on ``PYTHONPATH``, same interpreter) on the bundled bags and on the test
suite's chunked and damaged-bag fixtures, rebuilt here (zstd, lz4 and uncompressed copies of a
640x360 bag, a smashed zstd chunk, truncated images and a NaN robot pose), with 1 and 2
workers, and compares ``results.csv``, ``summary.json``, ``metadata.yaml`` and the output
bag's file byte for byte.)

Figures: docs/localization.md, "The whole `process` command". Latest, 2026-11-29 12:30 UTC,
``--curves length --compare <the code before> --repeat 2`` (least CPU of two runs, least floor
of two), zstd bags, 2-core machine at load 0.3-2.0:

* 20 s 640x480: 2.02 CPU-s, 1.91x the floor, CPU/wall 1.61 (the code before: 2.08, 1.96x,
  1.59); peak PSS of the tree 179 MB;
* 2 min: 10.65 CPU-s, 1.68x, CPU/wall 1.72; 188 MB;
* 10 min: 51.62 CPU-s, 1.60x, CPU/wall 1.72; 206 MB (by quarter of the run 199 / 203 / 205 /
  206);
* bag length: CPU 0.086 s per s of bag (R^2 1.0000), floor 0.054.

Targets, 2026-11-30 00:47 UTC, ``--curves length,targets --compare <the code before> --repeat
2``: 4 and 8 targets 1.98x and 2.03x the floor (the code before 2.16x and 2.48x), CPU 0.40 s
per target (R^2 0.9986); one target 1.86x / 1.63x / 1.64x for 20 s / 2 min / 10 min (the code
before 1.82x / 1.60x / 1.58x: within the runs' spread).

The first release (88607dc), 2026-11-30 04:20 UTC, ``--curves targets --compare /tmp/first
--repeat 2``, in a slower phase of the machine: zstd bags 1 / 4 / 8 targets 3.05 / 5.44 /
7.97 CPU-s against the first release's 3.77 / 6.56 / 10.87 (2.00x / 2.41x / 2.36x the floor
against 2.48x / 2.91x / 3.21x); uncompressed (``--storage none``) 2.63 / 4.72 / 7.68 against
2.88 / 4.47 / 7.49 (2.35x / 2.63x / 2.84x against 2.57x / 2.49x / 2.77x).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "build" / "bench-data" / "scaling"
LEFT, RIGHT = "/stereo/left/image_raw", "/stereo/right/image_raw"
RATE_HZ = 30.0
#: the topics a long bag carries (images, their camera_info, robot poses, ground truth)
TOPICS = (LEFT, RIGHT, "/stereo/left/camera_info", "/stereo/right/camera_info", "/ee_pose",
          "/ground_truth/target")

#: colours of the targets: (name, OpenCV hue 0-179); the first is the default world's red
HUES = (("red", 0), ("yellow", 30), ("green", 60), ("blue", 112), ("orange", 15),
        ("cyan", 90), ("purple", 135), ("magenta", 160))
HUE_HALF_WIDTH = 6


@dataclass(frozen=True)
class Point:
    """One measured configuration."""

    seconds: float
    width: int
    height: int
    targets: int

    @property
    def key(self) -> str:
        return f"{self.width}x{self.height}_t{self.targets}"


def _bgr_of_hue(hue: int) -> tuple[int, int, int]:
    import cv2

    hsv = np.array([[[hue, 210, 215]]], dtype=np.uint8)
    b, g, r = (int(v) for v in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0])
    return b, g, r


def world_for(width: int, height: int, targets: int) -> Any:
    """The default world at this image size with ``targets`` spheres (1: the default red
    sphere; more: spheres of distinct colours, 25 mm, on a grid 70 mm apart on the table)."""
    from eye_in_hand.sim import World
    from eye_in_hand.sim.world import Target

    world = World.default().with_image_size(width, height)
    if targets > 1:
        cx, cy = 0.48, 0.16
        grid = [(0, 0), (1, 0), (0, 1), (1, 1), (-1, 0), (0, -1), (-1, -1), (1, -1)]
        ts = [Target(name, np.array([cx + 0.07 * i, cy + 0.07 * j, 0.025]), 0.025,
                     _bgr_of_hue(hue))
              for (name, hue), (i, j) in zip(HUES[:targets], grid[:targets], strict=True)]
        world = replace(world, targets=ts)
    return world


def params_text(targets: int) -> str:
    """The ``detect_triangulate`` section for ``targets`` colours (a parameter file)."""
    if targets == 1:
        spec = {"red": ([170, 120, 70], [10, 255, 255], 0.035)}
    else:
        spec = {name: ([(hue - HUE_HALF_WIDTH) % 180, 120, 70],
                       [(hue + HUE_HALF_WIDTH) % 180, 255, 255], 0.025)
                for name, hue in HUES[:targets]}
    lines = ["/**/detect_triangulate:", "  ros__parameters:", "    method: dlt",
             f"    target_names: [{', '.join(spec)}]", "    targets:"]
    for name, (lo, hi, r) in spec.items():
        lines += [f"      {name}:", f"        lower: {lo}", f"        upper: {hi}",
                  f"        radius_m: {r}"]
    return "\n".join(lines) + "\n"


def hue_ranges(targets: int) -> list[tuple[tuple[int, int, int], tuple[int, int, int]]]:
    """The floor's thresholds: one (lower, upper) HSV range per target (a range across hue 0
    thresholds as two, as the detector does)."""
    if targets == 1:
        return [((170, 120, 70), (10, 255, 255))]
    return [(((hue - HUE_HALF_WIDTH) % 180, 120, 70), ((hue + HUE_HALF_WIDTH) % 180, 255, 255))
            for _name, hue in HUES[:targets]]


def base_bag(p: Point, distinct: int) -> Path:
    """``distinct`` rendered pairs of this configuration (zstd chunks), cached."""
    from eye_in_hand.errors import KinematicsError
    from eye_in_hand.sim.output import RenderOptions, write_bag

    d = DATA / f"base_{p.key}_{distinct}"
    if (d / "metadata.yaml").exists():
        return d
    shutil.rmtree(d, ignore_errors=True)
    world = world_for(p.width, p.height, p.targets)
    print(f"rendering {distinct} stereo pairs, {p.width}x{p.height}, {p.targets} target(s) ...",
          flush=True)
    for seed in range(12, 40):
        try:
            write_bag(world, d, scenario="localization", frames=distinct, seed=seed,
                      render=RenderOptions(noise_sigma=0.0))
            return d
        except KinematicsError:
            shutil.rmtree(d, ignore_errors=True)
    raise SystemExit(f"no reachable orbit for {p}")


_STAMP = struct.Struct("<iI")


def _restamp(raw: bytes, shift_ns: int) -> bytes:
    """A CDR message whose first field is a std_msgs/Header, its stamp moved by ``shift_ns``."""
    sec, nsec = _STAMP.unpack_from(raw, 4)
    t = sec * 1_000_000_000 + nsec + shift_ns
    return raw[:4] + _STAMP.pack(t // 1_000_000_000, t % 1_000_000_000) + raw[12:]


def long_bag(p: Point, storage: str, distinct: int) -> Path:
    """A ``p.seconds`` bag cycling the base bag's pairs with new stamps, cached. ``distinct``
    pairs at 640x480, fewer for larger images (as many pixels, at least 20 pairs): rendering
    is what costs here."""
    from eye_in_hand.io.bags import BagWriter, bag_info, iter_messages

    distinct = max(20, min(distinct, round(distinct * 640 * 480 / (p.width * p.height))))
    pairs = int(round(p.seconds * RATE_HZ))
    d = DATA / f"{p.key}_{pairs}p_{storage}"
    if (d / "metadata.yaml").exists():
        return d
    shutil.rmtree(d, ignore_errors=True)
    base = base_bag(p, distinct)
    info = bag_info(base)
    msgs = [(topic, t, bytes(raw)) for topic, _mt, t, raw in iter_messages(base, TOPICS)]
    image_t = sorted(t for topic, t, _ in msgs if topic == LEFT)
    period = int(round(1e9 / RATE_HZ))
    cycle = period * len(image_t)           # the base bag's images, back to back
    t0 = image_t[0] - period // 2           # a cycle: its images and the poses around them
    window = [(topic, t - t0, raw) for topic, t, raw in msgs if t0 <= t < t0 + cycle]
    print(f"writing {d.name} ({pairs} pairs) ...", flush=True)
    tmp = d.with_name(d.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    end = t0 + pairs * period               # the last pair at end - period/2
    with BagWriter(tmp, storage="mcap", compression=None if storage == "none" else "zstd") as w:
        for topic in TOPICS:
            w.add_topic(topic, info.topics[topic].msgtype)
        for c in range(-(-pairs // len(image_t))):
            shift = c * cycle
            for topic, dt, raw in window:
                t = t0 + shift + dt
                if t >= end:
                    break
                w.write(topic, t, _restamp(raw, shift) if shift else raw)
    tmp.rename(d)
    return d


def hand_eye_file(p: Point) -> Path:
    from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye

    world = world_for(p.width, p.height, p.targets)
    path = DATA / "hand_eye.yaml"
    if not path.exists():
        save_hand_eye(path, HandEyeCalibration("eye_in_hand", "tool0",
                                               "camera_left_optical_frame",
                                               np.asarray(world.ee_T_cam), method="truth"))
    return path


# -- measuring ---------------------------------------------------------------------------------
def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (from /proc/<pid>/task/*/children)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as fh:
                    todo.extend(int(c) for c in fh.read().split())
        except OSError:
            continue
    return out


def _pss(pid: int) -> int:
    """Proportional set size of a process in bytes (each page it shares divided among its
    sharers: a forked worker's pages shared with its parent count once in a sum), 0 once it
    is gone. Reading it walks the process's page tables, so it is sampled less often."""
    try:
        with open(f"/proc/{pid}/smaps_rollup") as fh:
            for line in fh:
                if line.startswith("Pss:"):
                    return int(line.split()[1]) * 1024
    except (OSError, IndexError, ValueError):
        pass
    return 0


def _mem(pid: int) -> tuple[int, int, int]:
    """(VmRSS, VmHWM, RssAnon) of a process in bytes (zeros once it is gone)."""
    got = {"VmRSS:": 0, "VmHWM:": 0, "RssAnon:": 0}
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                key = line.split(None, 1)[0]
                if key in got:
                    got[key] = int(line.split()[1]) * 1024
    except (OSError, IndexError, ValueError):
        pass
    return got["VmRSS:"], got["VmHWM:"], got["RssAnon:"]


def _env(code: Path | None) -> dict[str, str]:
    """The environment of a measured run: this one, with ``code`` first on ``PYTHONPATH``, and
    without the ROS wheels' re-exec guard, so that the command starts as from a shell (the
    venv's ``ros_wheels_bootstrapper.pth`` re-executes a fresh interpreter once, with the ROS
    libraries on ``LD_LIBRARY_PATH``)."""
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    if code is not None:
        env["PYTHONPATH"] = str(code)
    return env


#: the ``eye-in-hand`` console script's code, for any checkout
_CONSOLE = ("import sys, eye_in_hand.cli as cli\n"
            "entry = getattr(cli, 'console_main', None)\n"
            "sys.exit(entry() if entry else cli.main())\n")


def run_process(bag: Path, he: Path, params: Path, out: Path,
                code: Path | None = None) -> dict[str, Any]:
    """One ``eye-in-hand process`` run: wall, CPU of the tree, peak RSS (sum, largest);
    ``code``: another checkout whose ``eye_in_hand`` runs (first on ``PYTHONPATH``)."""
    shutil.rmtree(out, ignore_errors=True)
    # what the console script runs, from the checkout's own cli (its console_main, or main in
    # a checkout from before console_main): the venv's script names this checkout's entry
    cmd = [sys.executable, "-c", _CONSOLE]
    cmd += ["process", str(bag), "--hand-eye", str(he), "--params", str(params), "-o",
            str(out), "--quiet"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    peak = [0, 0, 0, 0]       # tree RSS sum, largest process's peak (VmHWM), tree anonymous,
    t0 = time.perf_counter()  # tree PSS (every fifth sample: a read walks the page tables,
    #                           about 0.4 ms for a 500 MB process)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(code), cwd=code or ROOT)   # not another checkout's root
    done = threading.Event()
    pss_at: list[tuple[float, int]] = []      # (s since start, tree PSS)

    def sample() -> None:
        k = 0
        while not done.wait(0.05):
            tree = _tree(proc.pid)
            mems = [_mem(q) for q in tree]
            peak[0] = max(peak[0], sum(m[0] for m in mems))
            peak[1] = max(peak[1], max((m[1] for m in mems), default=0))
            peak[2] = max(peak[2], sum(m[2] for m in mems))
            if k % 5 == 0:
                pss = sum(_pss(q) for q in tree)
                peak[3] = max(peak[3], pss)
                pss_at.append((time.perf_counter() - t0, pss))
            k += 1

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - t0
    done.set()
    sampler.join()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{stdout}{stderr}")
    summary = json.loads((out / "summary.json").read_text())
    shutil.rmtree(out, ignore_errors=True)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    # the peak tree PSS in each quarter of the run: flat from the second quarter on when
    # nothing is held per pair (the first holds the start-up and the workers' warm-up)
    quarters = [max((m for t, m in pss_at if q * wall / 4 <= t < (q + 1) * wall / 4),
                    default=0) / 1e6 for q in range(4)]
    return {"wall": wall, "pss_quarters": quarters, "cpu": cpu, "rss_sum": peak[0] / 1e6,
            "rss_max": peak[1] / 1e6,
            "anon_sum": peak[2] / 1e6, "pss_sum": peak[3] / 1e6,
            "pairs": float(summary["counts"]["pairs"]),
            "localized": float(summary["counts"]["localized"])}


def _quarters(run: dict[str, Any]) -> str:
    return "/".join(f"{m:.0f}" for m in run.get("pss_quarters", ()))


def floor(bag: Path, targets: int) -> dict[str, float]:
    """CPU of reading every image's bytes (chunks decompressed) and cvtColor + inRange (one
    per target) of both images of every pair, in one thread, with the heap of ``process``'s
    workers (:func:`eye_in_hand.io.pages.keep_freed_heap`): the least any ``process`` must
    do."""
    import cv2

    from eye_in_hand.io.bags import iter_messages
    from eye_in_hand.io.cdr import image_from_cdr
    from eye_in_hand.io.pages import keep_freed_heap

    # as process's workers: freed chunks and images are not given back to the kernel and
    # faulted in again for the next (about a third of the floor at 1920x1080 otherwise)
    keep_freed_heap()
    ranges = hue_ranges(targets)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    t_cpu, t0 = time.process_time(), time.perf_counter()
    n = 0
    try:
        for _topic, _mt, _t, raw in iter_messages(bag, [LEFT, RIGHT], views=True,
                                                  verify_crc=False):
            img = image_from_cdr(raw)
            assert img is not None
            bgr = np.frombuffer(img.data, np.uint8, img.height * img.step).reshape(
                img.height, img.width, 3)
            hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
            for lo, hi in ranges:
                if lo[0] > hi[0]:       # across hue 0: two ranges
                    cv2.inRange(hsv, lo, (179, hi[1], hi[2]))
                    cv2.inRange(hsv, (0, lo[1], lo[2]), hi)
                else:
                    cv2.inRange(hsv, lo, hi)
            n += 1
    finally:
        cv2.setNumThreads(threads)
    return {"floor_cpu": time.process_time() - t_cpu, "floor_wall": time.perf_counter() - t0,
            "images": float(n)}


#: run in a child interpreter by --startup: `eye-in-hand process` with timers around its phases
_PHASES = r"""
import resource, sys, time
def now():
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time(), ch.ru_utime + ch.ru_stime
rows = [("interpreter start-up", time.process_time(), 0.0)]
c0 = now()
import eye_in_hand, pathlib
# as the console script's main() does before the command loads numpy; not for a checkout from
# before it did (the editable install's finder would import this checkout's module instead)
if (pathlib.Path(eye_in_hand.__file__).parent / "threads.py").exists():
    from eye_in_hand.threads import one_blas_thread
    one_blas_thread()
import eye_in_hand.cli as cli
import eye_in_hand.commands.process as P
c1 = now()
import eye_in_hand.nodes.parameters as NP, eye_in_hand.offline as O, eye_in_hand.io.results as R
c2 = now()
rows += [("CLI imports", c1[0] - c0[0], 0.0), ("`process` imports", c2[0] - c1[0], 0.0)]
def wrap(mod, attr, label):
    fn = getattr(mod, attr)
    def timed(*a, **k):
        t0 = now()
        try:
            return fn(*a, **k)
        finally:
            t1 = now()
            # a part of the pass: the worker processes' CPU is the pass's (it is counted when
            # a worker is reaped, which can fall within a part: they exit as the bag's end is
            # settled)
            part = label.startswith("  of which")
            rows.append((label, t1[0] - t0[0], 0.0 if part else t1[1] - t0[1]))
    setattr(mod, attr, timed)
    if getattr(P, attr, None) is fn:     # the command imported it by name
        setattr(P, attr, timed)
wrap(NP, "check_parameter_file_keys", "--params key check")
wrap(O, "_rig_from_camera_info", "  of which: rig from camera_info")
wrap(R, "assign_truth", "  of which: ground-truth matching")
wrap(O, "process_bag", "the pass over the bag (main + worker processes)")
wrap(O, "write_results", "output files")
# wall time from the launch (the parent's clock, in the environment) to the first pair or
# chunk group handed to a worker process, and to the end of the pass
import os, eye_in_hand.workers as W
launched = float(os.environ.get("BENCH_LAUNCHED", "nan"))
walls = {}
def first_call(cls, attr, label):
    fn = getattr(cls, attr)
    def timed(self, *a, **k):
        got = fn(self, *a, **k)   # a task is sent once a worker is ready
        if got is not None:       # (try_submit_to: None when no worker took it)
            walls.setdefault(label, time.time() - launched)
        return got
    setattr(cls, attr, timed)
first_call(W.ProcessPool, "submit", "first task to a worker process")
first_call(W.ProcessPool, "try_submit_to", "first task to a worker process")
pass_fn = O.process_bag
def pass_timed(*a, **k):
    try:
        return pass_fn(*a, **k)
    finally:
        walls["end of the pass"] = time.time() - launched
O.process_bag = P.process_bag = pass_timed
sys.argv = ["eye-in-hand"] + sys.argv[1:]
try:
    cli.main()
except SystemExit:
    pass
end = now()
rows.append(("whole main process", end[0], end[1]))
for name, main, children in rows:
    print(f"PHASE\t{name}\t{main:.3f}\t{children:.3f}")
walls["exit"] = time.time() - launched
for name, seconds in walls.items():
    print(f"WALL\t{name}\t{seconds:.3f}")
"""


def startup(bag: Path, he: Path, params: Path, codes: list[Path | None], repeat: int) -> None:
    """CPU of the phases of `process` runs (the main process; worker processes as the
    children's CPU), the least of ``repeat`` runs per phase, and the wall time from the launch
    to the first task handed to a worker process, to the end of the pass and to the exit (the
    median of the runs); ``codes``: this checkout (None) and others, run alternately."""
    best: dict[Path | None, dict[str, tuple[float, float]]] = {c: {} for c in codes}
    walls: dict[Path | None, dict[str, list[float]]] = {c: {} for c in codes}
    order: list[str] = []
    for k in range(repeat):
        # alternating, the other checkout first every second round (as the curves)
        for code in codes if k % 2 == 0 else codes[::-1]:
            out = DATA / "out-startup"
            shutil.rmtree(out, ignore_errors=True)
            env = {**_env(code), "BENCH_LAUNCHED": repr(time.time())}
            t0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            proc = subprocess.run([sys.executable, "-c", _PHASES, "process", str(bag),
                                   "--hand-eye", str(he), "--params", str(params), "-o",
                                   str(out), "--quiet"], capture_output=True, text=True, env=env,
                                  cwd=code or ROOT)   # `-c` puts the working directory first
            t1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            if proc.returncode != 0:
                raise SystemExit(proc.stdout + proc.stderr)
            total = t1.ru_utime + t1.ru_stime - t0.ru_utime - t0.ru_stime
            lines = [line.split("\t") for line in proc.stdout.splitlines()]
            rows = [x[1:] for x in lines if x[0] == "PHASE"] + [
                ["whole tree (getrusage)", f"{total:.3f}", "0"]]
            for name, main, children in rows:
                if name not in order:
                    order.append(name)
                old = best[code].get(name)
                if old is None or float(main) + float(children) < sum(old):
                    best[code][name] = (float(main), float(children))
            for x in lines:
                if x[0] == "WALL":
                    walls[code].setdefault(x[1], []).append(float(x[2]))
    for code in codes:
        print(f"start-up and phases of `eye-in-hand process` ({code or 'this checkout'}), CPU "
              f"s, least of {repeat} runs (main process + its worker processes):")
        for name in order:
            if name in best[code]:
                main, children = best[code][name]
                print(f"  {name:45s} {main:6.3f}" + (f" + {children:6.3f}" if children else ""))
        print(f"  wall s from the launch, median of {repeat} runs:")
        for name, values in walls[code].items():
            print(f"    {name:43s} {statistics.median(values):6.3f}")


def fit(x: list[float], y: list[float]) -> tuple[float, float, float]:
    """Least-squares line y = a + b x: (slope b, intercept a, R^2)."""
    X, Y = np.asarray(x, float), np.asarray(y, float)
    b, a = np.polyfit(X, Y, 1)
    ss = float(np.sum((Y - Y.mean()) ** 2))
    r2 = 1.0 - float(np.sum((Y - (a + b * X)) ** 2)) / ss if ss > 0 else 1.0
    return float(b), float(a), r2


# -- identity of the outputs between two checkouts ---------------------------------------------
IDENTITY = DATA.parent / "identity"


def _copy_bag(src: Path, dst: Path, compression: str | None, edit: Any = None) -> None:
    """``src`` rewritten (chunks ``compression``: None, zstd or lz4), each message passed
    through ``edit(topic, index, raw)``, as the test fixtures do."""
    from eye_in_hand.io.bags import BagWriter, bag_info, iter_messages

    info = bag_info(src)
    seen: dict[str, int] = {}
    with BagWriter(dst, "mcap", None if compression is None else "zstd") as w:
        if compression == "lz4":
            import lz4.frame

            w._writer.storage.compression = "lz4"
            w._writer.storage.compressor = lz4.frame.compress
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, raw in iter_messages(src):
            k = seen[topic] = seen.get(topic, -1) + 1
            w.write(topic, stamp, edit(topic, k, raw) if edit else raw)


def identity_cases() -> list[tuple[str, Path, Path, list[str]]]:
    """(name, bag, hand_eye.yaml, extra args) of every case, fixtures built once."""
    from eye_in_hand.io.bags import default_typestore, deserialize, serialize
    from eye_in_hand.io.config import HandEyeCalibration, save_hand_eye
    from eye_in_hand.sim import World
    from eye_in_hand.sim.output import write_bag

    d = IDENTITY
    world = World.default().with_image_size(640, 360)
    he = d / "hand_eye.yaml"
    if not (d / "done").exists():
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        save_hand_eye(he, HandEyeCalibration("eye_in_hand", "tool0",
                                             "camera_left_optical_frame",
                                             np.asarray(world.ee_T_cam), method="ground_truth"))
        write_bag(world, d / "zstd", scenario="localization", frames=12, seed=5)
        _copy_bag(d / "zstd", d / "raw", None)
        _copy_bag(d / "zstd", d / "lz4", "lz4")
        # a smashed zstd chunk (the chunk of the 7th right image), as test_damaged_bags does
        shutil.copytree(d / "zstd", d / "zstd_smashed")
        mcap = next((d / "zstd_smashed").glob("*.mcap"))
        data = bytearray(mcap.read_bytes())
        at = _image_chunk_records(mcap, RIGHT, 6) + 40
        data[at:at + 64] = np.random.default_rng(7).integers(0, 256, 64, np.uint8).tobytes()
        mcap.write_bytes(bytes(data))
        store = default_typestore()

        def edit(topic: str, k: int, raw: bytes) -> bytes:
            if topic == LEFT and k in (4, 5):
                return raw[: len(raw) // 2]                 # truncated images
            if topic == "/ee_pose" and k == 100:
                msg = deserialize(raw, "geometry_msgs/msg/PoseStamped")
                msg.pose.position.x = float("nan")
                return serialize(msg, "geometry_msgs/msg/PoseStamped", store)
            return raw

        _copy_bag(d / "zstd", d / "raw_damaged", None, edit)
        _copy_bag(d / "zstd", d / "zstd_damaged", "zstd", edit)
        (d / "done").write_text("")
    cases = []
    for name in ("zstd", "raw", "lz4", "zstd_smashed", "raw_damaged", "zstd_damaged"):
        for workers in ("1", "2"):
            cases.append((f"{name}_w{workers}", d / name, he, ["--workers", workers]))
    bundled_he = d / "bundled_hand_eye.yaml"
    if not bundled_he.exists():
        save_hand_eye(bundled_he, HandEyeCalibration(
            "eye_in_hand", "tool0", "camera_left_optical_frame",
            np.asarray(World.default().ee_T_cam), method="ground_truth"))
    for name in ("localization", "calibration"):
        for workers in ("1", "2"):
            cases.append((f"bundled_{name}_w{workers}", ROOT / "bags" / name, bundled_he,
                          ["--workers", workers]))
    cases.append(("bundled_localization_params", ROOT / "bags" / "localization", bundled_he,
                  ["--params", str(ROOT / "config" / "eye_in_hand.yaml")]))
    return cases


def _image_chunk_records(mcap: Path, topic: str, k: int) -> int:
    """Where the records of the chunk holding the ``k``-th message of ``topic`` start."""
    from rosbags.rosbag2 import Reader

    from eye_in_hand.io.bags import iter_messages

    stamps = [s for _t, _m, s, _r in iter_messages(mcap.parent, [topic])]
    with Reader(mcap.parent) as reader:
        conn = next(c for c in reader.connections if c.topic == topic)
        hit = [c for c in reader.storage.storages[0].chunks
               if c.message_start_time <= stamps[k] <= c.message_end_time
               and c.channel_count.get(conn.id)]
    best = min(hit, key=lambda c: sum(c.channel_count.values()))
    data = mcap.read_bytes()
    (n,) = struct.unpack_from("<I", data, best.chunk_start_offset + 9 + 28)
    return int(best.chunk_start_offset) + 9 + 32 + n + 8


def identity(other: Path) -> int:
    """Run both checkouts on every case; 0 when every output file is byte-identical."""
    bad = 0
    cases = identity_cases()
    for name, bag, he, extra in cases:
        outs = []
        for label, tree in (("this", ROOT), ("other", other)):
            out = IDENTITY / "runs" / label / name / "out"   # same file names in both
            shutil.rmtree(out.parent, ignore_errors=True)
            out.parent.mkdir(parents=True)
            env = {**os.environ, "PYTHONPATH": str(tree)}
            proc = subprocess.run([sys.executable, "-m", "eye_in_hand.cli", "process", str(bag),
                                   "--hand-eye", str(he), "-o", str(out), "--quiet", *extra],
                                  env=env, capture_output=True, text=True, cwd=out.parent)
            outs.append((proc.returncode, proc.stdout, out))
        (rc_a, text_a, a), (rc_b, text_b, b) = outs
        files = sorted(p.name for p in a.iterdir()) if a.exists() else []
        same = rc_a == rc_b and files == (sorted(p.name for p in b.iterdir())
                                          if b.exists() else [])
        diff = [f for f in files if (a / f).read_bytes() != (b / f).read_bytes()]
        # printed lines but for the time taken and the output paths
        lines_a = [x for x in text_a.splitlines() if not x.startswith(("processed ", "wrote "))]
        lines_b = [x for x in text_b.splitlines() if not x.startswith(("processed ", "wrote "))]
        ok = same and not diff and lines_a == lines_b
        bad += not ok
        print(f"{'identical' if ok else 'DIFFERENT'}  {name}: exit {rc_a}/{rc_b}, "
              f"{len(files)} files ({', '.join(files)})" + (f"; differ: {diff}" if diff else "")
              + ("" if lines_a == lines_b else "; printed lines differ"), flush=True)
    print(f"{len(cases) - bad} of {len(cases)} cases identical")
    return 1 if bad else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--identity", metavar="OTHER_CHECKOUT", type=Path,
                        help="compare the outputs of this checkout's process with another's")
    parser.add_argument("--quick", action="store_true",
                        help="small bags and images (a few minutes)")
    parser.add_argument("--storage", choices=("zstd", "none"), default="zstd",
                        help="chunk compression of the synthesized bags (default zstd)")
    parser.add_argument("--curves", default="length,targets,size",
                        help="comma-separated subset of length,targets,size")
    parser.add_argument("--repeat", type=int, default=1,
                        help="process runs per point; the one of least CPU counts")
    parser.add_argument("--distinct", type=int, default=60,
                        help="distinct rendered pairs cycled in a 640x480 bag (default 60: "
                             "2 s; fewer for larger images, at least 20)")
    parser.add_argument("--fresh", action="store_true", help="render and write the bags again")
    parser.add_argument("--startup", nargs="?", const="shortest",
                        choices=("shortest", "longest"),
                        help="only the CPU of the phases of process runs, and the wall time to "
                             "the first task on a worker, on the shortest (default) or longest "
                             "bag of the chosen curves (with --compare: the other checkout "
                             "too, alternating)")
    parser.add_argument("--prepare", action="store_true",
                        help="only render and write the bags (cached), measure nothing")
    parser.add_argument("--compare", metavar="OTHER_CHECKOUT", type=Path,
                        help="also run OTHER_CHECKOUT's process on every point, alternating "
                             "with this checkout's (--repeat runs each; least CPU counts)")
    args = parser.parse_args()
    if args.identity is not None:
        return identity(args.identity.resolve())
    if args.fresh and DATA.exists():
        shutil.rmtree(DATA)
    DATA.mkdir(parents=True, exist_ok=True)
    if args.quick:
        lengths, sizes, short = (5.0, 10.0, 20.0), ((320, 240), (640, 480), (960, 540)), 5.0
        small = (320, 240)
    else:
        lengths, sizes, short = (20.0, 120.0, 600.0), ((640, 480), (1280, 720), (1920, 1080)), \
            20.0
        small = (640, 480)
    curves: dict[str, tuple[str, list[tuple[float, Point]]]] = {
        "length": ("s of bag", [(s, Point(s, *small, 1)) for s in lengths]),
        "targets": ("targets", [(float(n), Point(short, *small, n)) for n in (1, 4, 8)]),
        "size": ("Mpx per image", [(w * h / 1e6, Point(short, w, h, 1)) for w, h in sizes]),
    }
    chosen = [c.strip() for c in args.curves.split(",") if c.strip()]
    for c in chosen:
        if c not in curves:
            raise SystemExit(f"--curves: unknown curve {c!r}")
    points = sorted({p for c in chosen for _x, p in curves[c][1]},
                    key=lambda p: (p.seconds, p.width, p.targets))
    bags = {p: long_bag(p, args.storage, args.distinct) for p in points}
    he = hand_eye_file(points[0])
    if args.prepare:
        return 0
    if args.startup:
        p = points[0] if args.startup == "shortest" else points[-1]
        params = DATA / f"params_t{p.targets}.yaml"
        params.write_text(params_text(p.targets))
        print(f"bag: {bags[p].name}; load {os.getloadavg()[0]:.2f}")
        startup(bags[p], he, params,
                [None] + ([args.compare.resolve()] if args.compare else []), max(1, args.repeat))
        print(f"load {os.getloadavg()[0]:.2f}")
        return 0
    results: dict[Point, dict[str, float]] = {}
    load = os.getloadavg()
    print(f"load average before: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
          f"{os.cpu_count()} CPUs; storage {args.storage}", flush=True)
    for p in points:
        params = DATA / f"params_t{p.targets}.yaml"
        params.write_text(params_text(p.targets))
        runs, other, floors = [], [], []
        for k in range(args.repeat):
            # alternating, the other checkout first every second round (the first run of a
            # large uncompressed bag may find it partly out of the page cache)
            if args.compare is not None and k % 2:
                other.append(run_process(bags[p], he, params, DATA / "out",
                                         args.compare.resolve()))
            runs.append(run_process(bags[p], he, params, DATA / "out"))
            if args.compare is not None and not k % 2:
                other.append(run_process(bags[p], he, params, DATA / "out",
                                         args.compare.resolve()))
            # the floor as the runs: the least of --repeat measurements, each next to a run
            # (single measurements moved by 10-20 % over minutes on this machine)
            floors.append(floor(bags[p], p.targets))
        r = min(runs, key=lambda r: r["cpu"])
        r.update(min(floors, key=lambda f: f["floor_cpu"]))
        results[p] = r
        if other:
            o = min(other, key=lambda r: r["cpu"])
            mine = ", ".join(f"{x['cpu']:.2f}" for x in runs)
            theirs = ", ".join(f"{x['cpu']:.2f}" for x in other)
            print(f"      {args.compare} on the same bag: wall {o['wall']:.2f} s, CPU "
                  f"{o['cpu']:.2f} s ({o['cpu'] / p.seconds:.3f} s per s of bag) -> "
                  f"{o['cpu'] / r['floor_cpu']:.2f}x the floor, CPU/wall "
                  f"{o['cpu'] / o['wall']:.2f}, peak RSS {o['rss_sum']:.0f} MB (tree; "
                  f"anonymous {o['anon_sum']:.0f} MB; PSS by quarter of the run "
                  f"{_quarters(o)} MB), {o['rss_max']:.0f} MB (largest); "
                  f"CPU of the runs: this {mine}; other {theirs}", flush=True)
        bag_mb = sum(f.stat().st_size for f in bags[p].iterdir()) / 1e6
        print(f"{p.seconds:5.0f} s {p.width}x{p.height} {p.targets} target(s) ({bag_mb:,.0f} MB): "
              f"wall {r['wall']:.2f} s ({p.seconds / r['wall']:.1f}x real time), CPU "
              f"{r['cpu']:.2f} s ({r['cpu'] / p.seconds:.3f} s per s of bag), CPU/wall "
              f"{r['cpu'] / r['wall']:.2f}; floor {r['floor_cpu']:.2f} s CPU -> "
              f"{r['cpu'] / r['floor_cpu']:.2f}x the floor; peak RSS {r['rss_sum']:.0f} MB "
              f"(tree; anonymous {r['anon_sum']:.0f} MB; PSS {r['pss_sum']:.0f} MB, by quarter "
              f"of the run {_quarters(r)} MB), "
              f"{r['rss_max']:.0f} MB (largest process); {r['localized']:.0f} of "
              f"{r['pairs']:.0f} pairs localized; load {os.getloadavg()[0]:.2f}", flush=True)
    for c in chosen:
        unit, pts = curves[c]
        xs = [x for x, _p in pts]
        print(f"== {c}: least-squares lines against {unit} (R^2)")
        for key, label, scale in (("wall", "wall s", 1.0), ("cpu", "CPU s", 1.0),
                                  ("floor_cpu", "floor CPU s", 1.0),
                                  ("rss_sum", "peak RSS (tree) MB", 1.0),
                                  ("pss_sum", "peak PSS (tree) MB", 1.0),
                                  ("anon_sum", "peak anonymous (tree) MB", 1.0),
                                  ("rss_max", "peak RSS (largest) MB", 1.0)):
            ys = [results[p][key] * scale for _x, p in pts]
            b, a, r2 = fit(xs, ys)
            print(f"  {label:22s} slope {b:10.4f} per {unit}, intercept {a:8.3f}, R^2 "
                  f"{r2:.4f}   ({', '.join(f'{y:.2f}' for y in ys)})")
        ratio = [results[p]["cpu"] / results[p]["floor_cpu"] for _x, p in pts]
        per_wall = [results[p]["cpu"] / results[p]["wall"] for _x, p in pts]
        print(f"  CPU / floor: {', '.join(f'{v:.2f}' for v in ratio)}; CPU/wall: "
              f"{', '.join(f'{v:.2f}' for v in per_wall)}")
    load = os.getloadavg()
    print(f"load average after: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
