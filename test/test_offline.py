"""eye_in_hand.offline: where pairs are located never changes what is found."""
from __future__ import annotations

import time

import numpy as np
import pytest

from eye_in_hand.core.locator import load_locator_config
from eye_in_hand.core.sync import ApproximateStereoSync
from eye_in_hand.io.bags import BagWriter, bag_info, iter_messages, memory_mappable
from eye_in_hand.io.cdr import image_from_cdr
from eye_in_hand.io.config import HandEyeCalibration
from eye_in_hand.offline import ProcessOptions, _PairPool, process_bag
from eye_in_hand.ros.conversions import header_stamp_ns
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
        for a, b in zip(results[mode], results["inline"]):
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
    for other in runs[1:]:
        assert other.counts == first.counts
        for a, b in zip(other.frames, first.frames):
            assert a.stamp_ns == b.stamp_ns
            np.testing.assert_array_equal(a.point_base, b.point_base)


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

    pool = _PairPool(world.rig, cfg, 2)
    pool.start_processes()
    deadline = time.monotonic() + 60
    while not (pool._procs and all(w.ready.is_set() for w in pool._procs._workers)) \
            and time.monotonic() < deadline:
        time.sleep(0.01)
    victim = pool._procs._workers[0].proc.pid
    out = []
    try:
        for i, pair in enumerate(_pairs(raw)):
            pool.submit(pair)
            if i == 2:
                os.kill(victim, signal.SIGKILL)     # with pairs in flight on it
        out.extend(pool.ready(wait=True))
    finally:
        pool.close()
    assert [f.stamp_ns for f in out] == [f.stamp_ns for f in expected]
    for a, b in zip(out, expected):
        np.testing.assert_array_equal(a.point_cam, b.point_cam)
    assert any("worker process" in n for n in pool.notes), pool.notes
