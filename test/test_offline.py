"""eye_in_hand.offline: where pairs are located never changes what is found."""
from __future__ import annotations

import functools
import time

import numpy as np
import pytest

from eye_in_hand.core.locator_params import load_locator_config
from eye_in_hand.core.sync import ApproximateStereoSync
from eye_in_hand.io.bags import BagWriter, bag_info, iter_messages, memory_mappable
from eye_in_hand.io.cdr import image_from_cdr
from eye_in_hand.io.config import HandEyeCalibration
from eye_in_hand.offline import ProcessOptions, _PairPool, process_bag
from eye_in_hand.ros.stamps import header_stamp_ns
from eye_in_hand.sim import World
from eye_in_hand.sim.output import write_bag

LEFT, RIGHT = "/stereo/left/image_raw", "/stereo/right/image_raw"


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """The same 8-pair 640x360 localization bag, zstd chunks (as simulated) and uncompressed."""
    root = tmp_path_factory.mktemp("offline")
    world = World.default().with_image_size(640, 360)
    zstd = root / "zstd"
    write_bag(world, zstd, scenario="localization", frames=8, seed=5)
    raw = root / "raw"
    info = bag_info(zstd)
    with BagWriter(raw) as w:
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, data in iter_messages(zstd):
            w.write(topic, stamp, data)
    return world, zstd, raw


def _pairs(bag):
    """Stereo pairs as they are read (images are views of the file only while reading)."""
    sync = ApproximateStereoSync(5_000_000, 5)
    for topic, _mt, _t, raw in iter_messages(bag, [LEFT, RIGHT], views=True):
        img = image_from_cdr(raw)
        push = sync.push_left if topic == LEFT else sync.push_right
        yield from push(header_stamp_ns(img), img)


def test_worker_processes_thread_and_inline_give_identical_results(bags):
    world, zstd, raw = bags
    assert memory_mappable(raw) and not memory_mappable(zstd)
    cfg = load_locator_config(None)
    results = {}
    for mode in ("inline", "threads", "processes"):
        pool = _PairPool(world.rig, cfg, 1 if mode == "inline" else 2)
        if mode == "processes":
            pool.start_processes()
            deadline = time.monotonic() + 60
            while not (pool._procs and pool._procs.ready()) and time.monotonic() < deadline:
                time.sleep(0.01)
        out = []
        try:
            for pair in _pairs(raw if mode == "processes" else zstd):
                pool.submit(pair)
                out.extend(pool.ready())
            out.extend(pool.ready(wait=True))
        finally:
            pool.close()
        if mode == "processes":
            assert pool.in_processes == len(out) == 8 and not pool.notes
        results[mode] = out
    for mode in ("threads", "processes"):
        assert [f.stamp_ns for f in results[mode]] == [f.stamp_ns for f in results["inline"]]
        for a, b in zip(results[mode], results["inline"], strict=True):
            assert a.status == b.status == "located"
            np.testing.assert_array_equal(a.point_cam, b.point_cam)
            np.testing.assert_array_equal(a.cov_cam, b.cov_cam)


def test_process_bag_is_the_same_on_both_storages_and_any_worker_count(bags):
    world, zstd, raw = bags
    cfg = load_locator_config(None)
    he = HandEyeCalibration(setup="eye_in_hand", parent_frame="tool0",
                            child_frame="camera_left_optical_frame", transform=world.ee_T_cam,
                            method="ground_truth")
    runs = [process_bag(bag, hand_eye_T=he.transform, locator_config=cfg, rig=world.rig,
                        options=ProcessOptions(workers=w))
            for bag in (zstd, raw) for w in (1, 2)]
    first = runs[0]
    assert first.counts["localized"] == 8
    # summary.json lists the counts in this order (its bytes are compared between releases)
    assert list(first.counts) == [
        "pairs", "located", "localized", "no_target", "no_robot_pose", "bad_messages",
        "left_frames", "right_frames", "unpaired_left", "unpaired_right", "bad_pairs",
        "refused.stale_pose", "pose_buffer_resets", "time_jumps", "worker_timeouts",
        "pairs_relocated", "stale_stamp", "ground_truth", "damaged_regions", "messages_lost",
        "lost"]
    for other in runs[1:]:
        assert list(other.counts) == list(first.counts)
        assert other.counts == first.counts
        for a, b in zip(other.frames, first.frames, strict=True):
            assert a.stamp_ns == b.stamp_ns
            np.testing.assert_array_equal(a.point_base, b.point_base)


def test_workers_started_before_the_rig_is_read_give_the_same_results(bags):
    """process_bag starts its worker processes before it reads the rig from the bag's
    camera_info, and initialises them with it then: the same frames as in one thread, on
    both storages, and the pairs of compressed chunks (opened by the workers, which wait for
    them) were located in the processes."""
    world, zstd, raw = bags
    cfg = load_locator_config(None)
    runs = {(bag.name, w): process_bag(bag, hand_eye_T=world.ee_T_cam, locator_config=cfg,
                                       options=ProcessOptions(workers=w))
            for bag in (zstd, raw) for w in (1, 2)}
    first = runs[("zstd", 1)]
    assert first.counts["localized"] == 8 and first.located_in_processes == 0
    assert runs[("zstd", 2)].located_in_processes == 8
    for other in runs.values():
        assert not other.notes
        assert other.counts == first.counts
        for a, b in zip(other.frames, first.frames, strict=True):
            np.testing.assert_array_equal(a.point_cam, b.point_cam)
            np.testing.assert_array_equal(a.point_base, b.point_base)


_FORK_OR_SPAWN = """\
import json, sys, threading
import numpy as np
from eye_in_hand.core.locator_params import load_locator_config
from eye_in_hand.offline import ProcessOptions, process_bag
if sys.argv[2] == "thread":      # a second thread: forking is not safe, fresh interpreters
    stop = threading.Event()
    threading.Thread(target=stop.wait, daemon=True).start()
T = np.array(json.loads(sys.argv[3]))
res = process_bag(sys.argv[1], hand_eye_T=T, locator_config=load_locator_config(None),
                  options=ProcessOptions(workers=2))
print(json.dumps(dict(forked=res.workers_forked, in_processes=res.located_in_processes,
                      notes=res.notes, counts=res.counts,
                      points=[f.point_base.tolist() for f in res.frames])))
"""


def test_forked_and_spawned_workers_give_the_same_results(bags):
    """``process_bag`` in a process of one thread forks its worker processes, in one with
    another thread starts fresh interpreters: the same frames to the last bit, on both
    storages, located in the workers."""
    import json
    import os
    import subprocess
    import sys

    world, zstd, raw = bags
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    for bag in (zstd, raw):
        got = {}
        for how in ("plain", "thread"):
            run = subprocess.run([sys.executable, "-c", _FORK_OR_SPAWN, str(bag), how,
                                  json.dumps(world.ee_T_cam.tolist())],
                                 capture_output=True, text=True, env=env, timeout=300)
            assert run.returncode == 0, run.stderr
            got[how] = json.loads(run.stdout.strip().splitlines()[-1])
        assert got["plain"]["forked"] and not got["thread"]["forked"]
        for out in got.values():
            # compressed chunks: every pair in the workers that opened them. Mapped images
            # go to threads here until the first worker is ready: on a loaded machine that
            # can be after all 8 pairs, so their count is not asserted
            assert out["counts"]["pairs"] == 8 and not out["notes"]
            if bag is zstd:
                assert out["in_processes"] == 8
        assert got["plain"]["counts"] == got["thread"]["counts"]
        assert got["plain"]["points"] == got["thread"]["points"]


def _worker_children() -> list[int]:
    """This process's live ``eye_in_hand.workers`` children."""
    import os

    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat") as fh:
                stat = fh.read()
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                cmd = fh.read()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[1]) == os.getpid() and fields[0] != "Z" and b"workers" in cmd:
            found.append(int(pid))
    return found


def test_a_rig_that_cannot_be_read_leaves_no_worker_process(bags, monkeypatch):
    """Workers start before the rig is read from the bag; when that fails, the error is the
    reader's and no process is left behind (never initialised: killed, not waited for)."""
    import eye_in_hand.offline as offline
    from eye_in_hand.errors import BagError

    world, zstd, _raw = bags

    def unreadable(*_a, **_k):
        raise BagError("camera_info: cannot be read (planted)")

    monkeypatch.setattr(offline, "_rig_from_camera_info", unreadable)
    before = set(_worker_children())
    t0 = time.monotonic()
    with pytest.raises(BagError, match="planted"):
        process_bag(zstd, hand_eye_T=world.ee_T_cam, locator_config=load_locator_config(None),
                    options=ProcessOptions(workers=2))
    assert set(_worker_children()) <= before
    assert time.monotonic() - t0 < 10


def test_a_bag_without_camera_info_fails_before_any_worker_starts(bags, tmp_path,
                                                                  monkeypatch):
    """A bag that lacks a topic it needs is refused from its summary, before worker processes
    start (none is started only to be stopped)."""
    import eye_in_hand.workers as workers
    from eye_in_hand.errors import BagError

    world, zstd, _raw = bags
    bare = tmp_path / "no_info"
    info = bag_info(zstd)
    with BagWriter(bare) as w:
        for name, t in info.topics.items():
            if "camera_info" not in name:
                w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, data in iter_messages(zstd):
            if "camera_info" not in topic:
                w.write(topic, stamp, data)

    def no_pool(*_a, **_k):
        raise AssertionError("a worker pool was started")

    monkeypatch.setattr(workers, "ProcessPool", no_pool)
    with pytest.raises(BagError, match="camera_info"):
        process_bag(bare, hand_eye_T=world.ee_T_cam, locator_config=load_locator_config(None),
                    options=ProcessOptions(workers=2))


def test_worker_processes_start_before_the_rig_is_read(bags, monkeypatch):
    """The order that lets the workers import while the bag's rig is read: the pool starts
    (its initialisation deferred), then camera_info is read, then the workers get the rig."""
    import eye_in_hand.offline as offline
    import eye_in_hand.workers as workers

    world, zstd, _raw = bags
    events: list[str] = []
    real_pool, real_rig = workers.ProcessPool, offline._rig_from_camera_info

    class Pool(real_pool):  # type: ignore[misc, valid-type]
        def __init__(self, *a, **k):
            events.append(f"start defer_init={k.get('defer_init')}")
            super().__init__(*a, **k)

        def initialize(self, *a):
            events.append("initialize")
            super().initialize(*a)

    def rig(*a, **k):
        events.append("rig")
        return real_rig(*a, **k)

    monkeypatch.setattr(workers, "ProcessPool", Pool)
    monkeypatch.setattr(offline, "_rig_from_camera_info", rig)
    res = process_bag(zstd, hand_eye_T=world.ee_T_cam, locator_config=load_locator_config(None),
                      options=ProcessOptions(workers=2))
    assert events == ["start defer_init=True", "rig", "initialize"]
    assert res.located_in_processes == 8


def _ready_pool(world, cfg, **kw):
    """A pool of two worker processes, both started and initialised."""
    pool = _PairPool(world.rig, cfg, 2, **kw)
    pool.start_processes()
    assert pool._procs.wait_ready(60) and all(w.ready.is_set() for w in pool._procs._workers)
    return pool


def test_a_worker_process_that_dies_costs_no_pair(bags):
    import os
    import signal

    world, zstd, raw = bags
    cfg = load_locator_config(None)
    inline = _PairPool(world.rig, cfg, 1)
    expected = []
    for pair in _pairs(raw):
        inline.submit(pair)
    expected = list(inline.ready(wait=True))
    inline.close()

    pool = _ready_pool(world, cfg)
    victim = pool._procs._workers[0].proc.pid
    os.kill(victim, signal.SIGSTOP)     # stopped first: the pairs sent to it stay in flight
    out = []
    try:
        for i, pair in enumerate(_pairs(raw)):
            pool.submit(pair)
            if i == 2:
                assert pool._procs._workers[0].pending   # the least busy worker took some
                os.kill(victim, signal.SIGKILL)          # with pairs in flight on it
        out.extend(pool.ready(wait=True))
    finally:
        pool.close()
    assert pool.relocated >= 1
    assert [f.stamp_ns for f in out] == [f.stamp_ns for f in expected]
    for a, b in zip(out, expected, strict=True):
        np.testing.assert_array_equal(a.point_cam, b.point_cam)
    assert [n for n in pool.notes if f"worker process {victim} " in n], pool.notes


def test_a_worker_process_that_dies_between_pairs_is_noted(bags):
    """A worker that dies owing nothing fails no pair, but the pass ran with one worker less:
    the notes say so, once, naming the process and how it ended."""
    import os
    import signal

    world, _zstd, raw = bags
    cfg = load_locator_config(None)
    pool = _ready_pool(world, cfg)
    worker = pool._procs._workers[0]
    os.kill(worker.proc.pid, signal.SIGKILL)
    deadline = time.monotonic() + 60
    while not worker.dead and time.monotonic() < deadline:
        time.sleep(0.01)
    assert worker.dead
    try:
        for pair in _pairs(raw):
            pool.submit(pair)
        out = list(pool.ready(wait=True))
    finally:
        pool.close()
    assert len(out) == len(list(_pairs(raw))) and pool.relocated == 0
    assert pool.notes == [f"worker process {worker.proc.pid} was killed by SIGKILL during the "
                          "pass; the other workers and this process located the pairs left"]


def _ledger_ok(c):
    assert c["left_frames"] == c["pairs"] + c["unpaired_left"], c
    assert c["right_frames"] == c["pairs"] + c["unpaired_right"], c
    assert c["pairs"] == c["localized"] + c["no_target"] + c["no_robot_pose"] + c["bad_pairs"], c
    assert c["no_robot_pose"] == sum(v for k, v in c.items() if k.startswith("refused.")), c


def test_images_replayed_after_the_robot_poses_give_no_pose(bags, tmp_path):
    """Issue #14 offline: a bag holding one pass with /ee_pose and a second pass with only the
    images (same stamps, seconds later): the second pass gives no pose, and it is counted."""
    world, zstd, _raw = bags
    info = bag_info(zstd)
    replay = tmp_path / "replay"
    later = info.duration_ns + 5_000_000_000
    with BagWriter(replay) as w:
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, data in iter_messages(zstd):
            w.write(topic, stamp, data)
        for topic, _mt, stamp, data in iter_messages(zstd, [LEFT, RIGHT]):
            w.write(topic, stamp + later, data)       # the header stamps are the first pass's
    cfg = load_locator_config(None)
    res = process_bag(replay, hand_eye_T=world.ee_T_cam, locator_config=cfg, rig=world.rig,
                      options=ProcessOptions(workers=1, pose_jump_back_s=0.1))  # 0.27 s bag
    c = res.counts
    assert c["localized"] == 8 and c["pairs"] == 16, c
    assert c["refused.stale_pose"] == 8 and c["no_robot_pose"] == 8, c
    assert c["time_jumps"] == 1
    _ledger_ok(c)
    # Planted: without the age rule the 8 stale pairs come out (the bug of the issue).
    loose = process_bag(replay, hand_eye_T=world.ee_T_cam, locator_config=cfg, rig=world.rig,
                        options=ProcessOptions(workers=1, pose_jump_back_s=0.1,
                                               max_pose_age_s=1e6))
    assert loose.counts["localized"] == 16


def test_pairs_still_waiting_for_a_robot_pose_at_the_end_are_refused(bags, tmp_path):
    """The robot poses stop before the images: the last pairs wait in the pipeline for a pose
    at or after their stamp until the bag ends, then are refused (no_newer_pose), counted."""
    world, zstd, _raw = bags
    info = bag_info(zstd)
    lefts = sorted(s for _t, _mt, s, _d in iter_messages(zstd, [LEFT]))
    cut_ns = (lefts[4] + lefts[5]) // 2            # between the 5th and the 6th pair
    cut = tmp_path / "poses_stop"
    with BagWriter(cut) as w:
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, data in iter_messages(zstd):
            if topic == "/ee_pose" and stamp > cut_ns:
                continue
            w.write(topic, stamp, data)
    res = process_bag(cut, hand_eye_T=world.ee_T_cam, locator_config=load_locator_config(None),
                      rig=world.rig, options=ProcessOptions(workers=1))
    c = res.counts
    assert c["localized"] == 5 and c["no_robot_pose"] == 3, c
    assert c["refused.no_newer_pose"] == 3, c
    assert [f.status for f in res.frames] == ["ok"] * 5 + ["no_robot_pose"] * 3
    assert all(f.point_base is None for f in res.frames[5:])
    _ledger_ok(c)


def test_every_unpaired_image_is_counted(bags, tmp_path):
    world, zstd, _raw = bags
    info = bag_info(zstd)
    cut = tmp_path / "cut"
    dropped = 0
    with BagWriter(cut) as w:
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        k = 0
        for topic, _mt, stamp, data in iter_messages(zstd):
            if topic == RIGHT:
                k += 1
                if k in (2, 5, 8):                   # three right images lost
                    dropped += 1
                    continue
            w.write(topic, stamp, data)
    res = process_bag(cut, hand_eye_T=world.ee_T_cam, locator_config=load_locator_config(None),
                      rig=world.rig, options=ProcessOptions(workers=1))
    c = res.counts
    assert c["pairs"] == 8 - dropped and c["unpaired_left"] == dropped, c
    assert c["unpaired_right"] == 0 and c["left_frames"] == 8 and c["right_frames"] == 5
    _ledger_ok(c)


def test_a_stopped_worker_process_times_out_and_costs_no_pair(bags):
    """SIGSTOP a worker with pairs in flight: process_bag's pool kills it at the deadline,
    locates its pairs again here, and finishes with every result."""
    import os
    import signal

    world, _zstd, raw = bags
    cfg = load_locator_config(None)
    inline = _PairPool(world.rig, cfg, 1)
    for pair in _pairs(raw):
        inline.submit(pair)
    expected = list(inline.ready(wait=True))
    inline.close()

    pool = _ready_pool(world, cfg, task_timeout_s=1.0)
    victim = pool._procs._workers[0].proc.pid
    os.kill(victim, signal.SIGSTOP)                   # stopped, not dead: it never answers
    t0 = time.monotonic()
    out = []
    try:
        for pair in _pairs(raw):
            pool.submit(pair)
        out.extend(pool.ready(wait=True))
    finally:
        pool.close()
    assert time.monotonic() - t0 < 30
    assert pool.timeouts == 1 and pool.relocated >= 1
    assert [f.stamp_ns for f in out] == [f.stamp_ns for f in expected]
    for a, b in zip(out, expected, strict=True):
        np.testing.assert_array_equal(a.point_cam, b.point_cam)
    assert any("task deadline" in n for n in pool.notes), pool.notes


def test_idle_work_runs_once_each_and_changes_no_result(bags):
    """``process_bag(..., idle=...)``: each item runs exactly once, in order, while the pass
    waits for its workers or at its end, with workers or without; the frames are the same."""
    world, zstd, raw = bags
    cfg = load_locator_config(None)
    for workers in (1, 2):
        calls: list[str] = []
        res = process_bag(zstd, hand_eye_T=world.ee_T_cam, locator_config=cfg,
                          options=ProcessOptions(workers=workers),
                          idle=[functools.partial(calls.append, "a"),
                                functools.partial(calls.append, "b")])
        plain = process_bag(zstd, hand_eye_T=world.ee_T_cam, locator_config=cfg,
                            options=ProcessOptions(workers=workers))
        assert calls == ["a", "b"]
        assert res.counts == plain.counts and res.counts["localized"] == 8
        for a, b in zip(res.frames, plain.frames, strict=True):
            np.testing.assert_array_equal(a.point_base, b.point_base)


def test_a_frame_from_a_worker_keeps_no_part_of_its_pickle():
    """Every frame is kept until the outputs are written: one made from a worker's values owns
    its arrays (not views of the unpickled buffer, three objects each), shares its id
    strings with the other frames, and has no per-instance dict."""
    import pickle
    import sys

    from eye_in_hand.offline import _frame_of

    cov = np.diag([1e-8, 2e-8, 4e-8])
    values = (7, "located", "", [("red_0", "red", np.array([0.1, 0.2, 0.6]), cov, 0.25,
                                  np.array([640.5, 360.25]), np.array([600.5, 360.0]))], {})
    frame = _frame_of(pickle.loads(pickle.dumps(values, protocol=pickle.HIGHEST_PROTOCOL)))
    t = frame.targets[0]
    for a in (t.point_cam, t.cov_cam, t.left_px, t.right_px, frame.point_cam, frame.cov_cam):
        assert a.base is None and a.flags.owndata
    assert frame.point_cam is t.point_cam                 # the first target's, not a copy
    np.testing.assert_array_equal(t.cov_cam, cov)
    assert t.id is sys.intern("red_0") and t.name is sys.intern("red")
    assert not hasattr(frame, "__dict__") and not hasattr(t, "__dict__")


def test_robot_poses_are_kept_for_a_window_of_stamps_not_for_the_whole_bag(bags, tmp_path,
                                                                            monkeypatch):
    """``process`` prunes the pose buffer to ``POSE_HISTORY_S`` before the oldest frame that
    may still need a pose: here a window of 0 s, pruned at every frame (only the pose that
    brackets that frame's stamp and those after it stay), gives the very frames of the
    whole-bag buffer while holding a fraction of the poses."""
    from eye_in_hand import offline
    from eye_in_hand.core.sync import PoseBuffer

    world, zstd, _raw = bags
    cfg = load_locator_config(None)
    # the robot poses logged 0.2 s late: frames wait for them in the pipeline, and the
    # window counts from the oldest waiting frame, not from the frame taken last
    late = tmp_path / "late"
    info = bag_info(zstd)
    pose_topic = ProcessOptions().pose_topic
    with BagWriter(late) as w:
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, data in iter_messages(zstd):
            w.write(topic, stamp + (200_000_000 if topic == pose_topic else 0), data)

    def run():
        return process_bag(late, hand_eye_T=world.ee_T_cam, locator_config=cfg,
                           options=ProcessOptions(workers=1))

    whole = run()
    kept: list[tuple[int, int]] = []
    forget = PoseBuffer.forget_before

    def spy(self, stamp_ns):
        dropped = forget(self, stamp_ns)
        kept.append((dropped, len(self)))
        return dropped

    monkeypatch.setattr(PoseBuffer, "forget_before", spy)
    monkeypatch.setattr(offline, "POSE_HISTORY_S", 0.0)
    monkeypatch.setattr(offline, "_FORGET_EVERY", 1)
    pruned = run()
    n_poses = info.topics[pose_topic].count
    assert len(kept) == len(whole.frames) == 8
    assert sum(d for d, _ in kept) > 0 and max(n for _, n in kept) < n_poses / 2, (kept, n_poses)
    assert pruned.counts == whole.counts and whole.counts["localized"] == 8
    for a, b in zip(pruned.frames, whole.frames, strict=True):
        assert (a.stamp_ns, a.status, a.reason) == (b.stamp_ns, b.status, b.reason)
        np.testing.assert_array_equal(a.point_base, b.point_base)
        np.testing.assert_array_equal(a.cov_base, b.cov_base)


def test_frames_kept_in_a_file_give_the_same_outputs_byte_for_byte(bags, tmp_path,
                                                                   monkeypatch):
    """On a long bag ``process`` keeps the frames the pipeline is done with in a temporary
    file (:class:`~eye_in_hand.io.spill.SpillList`). Here every settled frame goes there at
    once, on a bag whose robot poses are logged 0.2 s late (frames wait several images for
    theirs) and stop after the fifth pair (the last three wait to the end of the bag, then are
    refused): the output bag, results.csv and summary.json are those of a run that keeps every
    frame in memory, byte for byte. A frame still waiting must not go to the file, and the
    ground truth, matched after the bag was read, reaches the frames in it."""
    from eye_in_hand import offline
    from eye_in_hand.io import spill
    from eye_in_hand.offline import write_results

    world, zstd, _raw = bags
    cfg = load_locator_config(None)
    info = bag_info(zstd)
    pose_topic = ProcessOptions().pose_topic
    lefts = sorted(s for _t, _mt, s, _d in iter_messages(zstd, [LEFT]))
    cut_ns = (lefts[4] + lefts[5]) // 2
    bag = tmp_path / "late_then_none"
    with BagWriter(bag) as w:
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, data in iter_messages(zstd):
            if topic == pose_topic:
                if stamp > cut_ns:
                    continue
                stamp += 200_000_000
            w.write(topic, stamp, data)
    opts = ProcessOptions(workers=1)

    def run(out):
        res = process_bag(bag, hand_eye_T=world.ee_T_cam, locator_config=cfg, options=opts)
        write_results(out, res, opts)
        return res

    whole = run(tmp_path / "in_memory" / "out")
    assert whole.frames.spilled == 0
    monkeypatch.setattr(spill, "KEEP", 0)
    monkeypatch.setattr(spill, "BATCH", 1)
    monkeypatch.setattr(offline, "_FORGET_EVERY", 1)
    filed = run(tmp_path / "in_a_file" / "out")
    c = whole.counts
    assert c["localized"] == 5 and c["refused.no_newer_pose"] == 3 and c["ground_truth"], c
    assert filed.counts == c
    assert filed.frames.spilled >= 1, filed.frames.spilled
    a, b = tmp_path / "in_memory" / "out", tmp_path / "in_a_file" / "out"
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    assert "results.csv" in names and "summary.json" in names and len(names) >= 4
    for name in names:
        assert (b / name).read_bytes() == (a / name).read_bytes(), name


def test_the_truth_matched_from_what_was_gathered_is_the_truth_read_from_the_frames(bags):
    """``process`` gathers the target ids and each id's base-frame positions as it takes and
    locates the frames, so that matching the ground truth reads none of them back: the ids,
    the match and every frame's truth are those of ``target_order`` and ``assign_truth``
    reading the frames."""
    import copy

    from eye_in_hand.io.bags import deserialize
    from eye_in_hand.io.results import TruthTable, assign_truth, target_order
    from eye_in_hand.ros.geometry import point_to_xyz

    world, zstd, _raw = bags
    cfg = load_locator_config(None)
    res = process_bag(zstd, hand_eye_T=world.ee_T_cam, locator_config=cfg,
                      options=ProcessOptions(workers=1))
    truth = TruthTable()
    for _t, mt, _s, raw in iter_messages(zstd, [ProcessOptions().ground_truth_topic]):
        msg = deserialize(raw, mt)
        truth.add(header_stamp_ns(msg), point_to_xyz(msg.point))
    assert len(truth) == res.counts["ground_truth"] == 8
    frames = [copy.deepcopy(f) for f in res.frames]
    for f in frames:
        f.truth_base, f.truth_by_id = None, {}
        for t in f.targets:
            t.truth_base = None
    names = [t.name for t in cfg.detector.targets]
    assert target_order(frames, names) == res.target_ids == ["red"]
    assert assign_truth(frames, truth, res.target_ids) == res.truth_match
    assert res.truth_match["red"]["distance_mm"] < 5.0
    for a, b in zip(frames, res.frames, strict=True):
        assert a.truth_base is not None and a.truth_base.tobytes() == b.truth_base.tobytes()


def test_frames_stay_in_memory_when_their_file_cannot_be_written(bags, monkeypatch):
    """No space for the frames' temporary file: the run goes on with them in memory, gives
    the same frames, and its notes say why and how to avoid it."""
    from eye_in_hand import offline
    from eye_in_hand.io import spill

    world, zstd, _raw = bags
    cfg = load_locator_config(None)

    def run():
        return process_bag(zstd, hand_eye_T=world.ee_T_cam, locator_config=cfg,
                           options=ProcessOptions(workers=1))

    whole = run()
    monkeypatch.setattr(spill, "KEEP", 0)
    monkeypatch.setattr(spill, "BATCH", 1)
    monkeypatch.setattr(offline, "_FORGET_EVERY", 1)

    def no_space(*_a, **_k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(spill.tempfile, "TemporaryFile", no_space)
    kept = run()
    assert kept.frames.spilled == 0 and kept.counts == whole.counts
    (note,) = [n for n in kept.notes if "TMPDIR" in n]
    assert "No space left on device" in note and "8 of the 8 frames" in note, note
    for a, b in zip(kept.frames, whole.frames, strict=True):
        np.testing.assert_array_equal(a.point_base, b.point_base)
