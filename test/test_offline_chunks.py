"""eye_in_hand.offline on compressed MCAP bags: chunks opened by the worker processes give the
same results as the uncompressed bag, the serial reader and one worker."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from eye_in_hand.core.locator_params import load_locator_config
from eye_in_hand.io.bags import BagWriter, bag_info, iter_messages, mcap_tasks
from eye_in_hand.io.bags.streams import worker_readable
from eye_in_hand.offline import ProcessOptions, process_bag, write_results
from eye_in_hand.sim import World
from eye_in_hand.sim.output import write_bag

LEFT = "/stereo/left/image_raw"


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """A 7-pair 640x360 localization bag with zstd chunks (as simulated) and its uncompressed
    copy (7 pairs: the last chunk holds a pair of its own)."""
    root = tmp_path_factory.mktemp("chunks")
    world = World.default().with_image_size(640, 360)
    zstd = root / "zstd"
    write_bag(world, zstd, scenario="localization", frames=7, seed=5)
    raw = root / "raw"
    info = bag_info(zstd)
    with BagWriter(raw) as w:
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, data in iter_messages(zstd):
            w.write(topic, stamp, data)
    return world, zstd, raw


def _copy(src, dst, compression):
    """``src`` rewritten with chunks compressed by ``compression`` ("lz4": rosbags writes zstd
    only, so the writer's codec is swapped)."""
    import lz4.frame

    info = bag_info(src)
    with BagWriter(dst, "mcap", "zstd") as w:
        if compression == "lz4":
            w._writer.storage.compression = "lz4"
            w._writer.storage.compressor = lz4.frame.compress
        for name, t in info.topics.items():
            w.add_topic(name, t.msgtype)
        for topic, _mt, stamp, data in iter_messages(src):
            w.write(topic, stamp, data)


def _run(world, bag, workers):
    return process_bag(bag, hand_eye_T=world.ee_T_cam, locator_config=load_locator_config(None),
                       rig=world.rig, options=ProcessOptions(workers=workers))


def _csv(result, out):
    return (write_results(out, result)["csv"]).read_text()


def test_zstd_bag_in_workers_gives_the_uncompressed_results(bags, tmp_path):
    world, zstd, raw = bags
    assert worker_readable(zstd) and not worker_readable(raw)
    in_workers = _run(world, zstd, 2)
    assert in_workers.located_in_processes == in_workers.counts["pairs"] == 7
    assert in_workers.counts["localized"] == 7 and not in_workers.notes
    reference = _run(world, raw, 1)
    serial = _run(world, zstd, 1)                 # the serial reader, one process
    assert in_workers.counts == reference.counts == serial.counts
    text = _csv(in_workers, tmp_path / "a")
    assert text == _csv(reference, tmp_path / "b") == _csv(serial, tmp_path / "c")
    assert text.count("\n") == 8


def test_pairs_split_over_groups_and_workers(bags, monkeypatch, tmp_path):
    world, zstd, raw = bags
    monkeypatch.setattr(mcap_tasks, "GROUP_BYTES", 1)     # every chunk a group of its own
    split = _run(world, zstd, 2)
    assert split.located_in_processes == 7
    assert _csv(split, tmp_path / "a") == _csv(_run(world, raw, 1), tmp_path / "b")


def test_lz4_chunks_take_the_same_path(bags, tmp_path):
    world, _zstd, raw = bags
    lz4 = tmp_path / "lz4"
    _copy(raw, lz4, "lz4")
    assert worker_readable(lz4)
    res = _run(world, lz4, 2)
    assert res.located_in_processes == 7 and not res.notes
    assert _csv(res, tmp_path / "a") == _csv(_run(world, raw, 1), tmp_path / "b")


def _chunk_of_image(mcap, k):
    """(offset, data offset) of the chunk record holding the k-th left image, by a scan of
    the file and the summary's message index (rosbags' reader)."""
    from rosbags.rosbag2 import Reader

    with Reader(mcap.parent) as reader:
        storage = reader.storage.storages[0] if hasattr(reader.storage, "storages") \
            else reader.storage
        cid = next(c.id for c in storage.connections if c.topic == LEFT)
        chunks = sorted((c for c in storage.chunks if c.channel_count.get(cid)),
                        key=lambda c: c.chunk_start_offset)
        off = chunks[k].chunk_start_offset
    data = mcap.read_bytes()
    (n,) = struct.unpack_from("<I", data, off + 9 + 28)
    return off, off + 9 + 32 + n + 8


def test_a_damaged_chunk_is_skipped_and_counted_as_by_the_serial_reader(bags, tmp_path):
    import shutil

    world, zstd, _raw = bags
    bad = tmp_path / "bad"
    shutil.copytree(zstd, bad)
    mcap = next(bad.glob("*.mcap"))
    off, data_at = _chunk_of_image(mcap, 3)
    data = bytearray(mcap.read_bytes())
    data[data_at + 2:data_at + 66] = np.random.default_rng(1).integers(0, 256, 64,
                                                                     np.uint8).tobytes()
    mcap.write_bytes(bytes(data))
    in_workers, serial = _run(world, bad, 2), _run(world, bad, 1)
    assert [d.where for d in in_workers.damage.records] == [f"chunk at byte {off}"]
    assert in_workers.damage.records == serial.damage.records
    assert in_workers.counts == serial.counts
    assert in_workers.counts["damaged_regions"] == 1 and in_workers.counts["messages_lost"] >= 1
    assert in_workers.counts["pairs"] == in_workers.counts["left_frames"] == 6
    assert _csv(in_workers, tmp_path / "a") == _csv(serial, tmp_path / "b")


def test_a_stopped_worker_costs_no_chunk_and_no_pair(bags, monkeypatch):
    """SIGSTOP a worker before it opens its chunks: its tasks miss the deadline, its chunks
    are opened here and its pairs located elsewhere, and every result is the same."""
    import os
    import signal
    import time

    from eye_in_hand.core.sync import ApproximateStereoSync
    from eye_in_hand.io.bags import typestore_for
    from eye_in_hand.io.bags.streams import decoded_stream
    from eye_in_hand.offline import _PairPool
    from eye_in_hand.ros.stamps import header_stamp_ns

    world, zstd, _raw = bags
    cfg = load_locator_config(None)
    topics = [LEFT, "/stereo/right/image_raw"]

    def located(pool, submit):
        sync = ApproximateStereoSync(5_000_000, 5)
        out = []
        for topic, _t, msg in decoded_stream(zstd, topics, typestore_for(zstd), submit=submit,
                                             image_topics=tuple(topics)):
            push = sync.push_left if topic == LEFT else sync.push_right
            for pair in push(header_stamp_ns(msg), msg):
                pool.submit(pair)
            out.extend(pool.ready())
        out.extend(pool.ready(wait=True))
        pool.close()
        return out

    expected = located(_PairPool(world.rig, cfg, 1), None)
    monkeypatch.setattr(mcap_tasks, "GROUP_BYTES", 1)   # groups alternate between the workers
    pool = _PairPool(world.rig, cfg, 2, task_timeout_s=1.0)
    pool.start_processes()
    assert pool._procs.wait_ready(60)
    os.kill(pool._procs._workers[0].proc.pid, signal.SIGSTOP)
    t0 = time.monotonic()
    out = located(pool, pool.submit_chunks)
    assert time.monotonic() - t0 < 30
    assert pool.timeouts == 1 and pool.in_processes >= 1
    assert [f.stamp_ns for f in out] == [f.stamp_ns for f in expected] and len(out) == 7
    for a, b in zip(out, expected, strict=True):
        assert a.status == b.status == "located"
        np.testing.assert_array_equal(a.point_cam, b.point_cam)
