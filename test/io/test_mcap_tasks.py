"""eye_in_hand.io.bags.mcap_tasks / io.bags.chunked: chunks opened by workers give the serial
reader's messages, in its order, with its damage records."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.io.bags import (
    BagWriter,
    DamageLog,
    default_typestore,
    iter_messages,
    mcap_tasks,
    serialize,
)
from eye_in_hand.io.bags.streams import iter_in_workers, worker_readable
from eye_in_hand.workers import ProcessPool

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
STRING = "std_msgs/msg/String"
IMAGE = "sensor_msgs/msg/Image"


def _write(path: Path, compression: str = "zstd", n: int = 60) -> None:
    """Strings on /a and /b and small images on /left and /right, 10 ms apart, mixed in
    chunks of about 1 MiB (as ``ros2 bag record`` mixes topics)."""
    store = default_typestore()
    T = store.types
    rng = np.random.default_rng(5)
    with BagWriter(path, "mcap", "zstd") as bag:
        if compression == "lz4":                  # rosbags writes zstd only: swap the codec
            import lz4.frame

            bag._writer.storage.compression = "lz4"
            bag._writer.storage.compressor = lz4.frame.compress
        for topic, mt in (("/a", STRING), ("/b", STRING), ("/left", IMAGE), ("/right", IMAGE)):
            bag.add_topic(topic, mt)
        for i in range(n):
            t = T0 + i * 10 * MS
            text = f"{i}:" + rng.integers(97, 103, 30_000, dtype=np.uint8).tobytes().decode()
            bag.write("/a" if i % 3 else "/b", t, serialize(T[STRING](data=text), STRING))
            if i % 2 == 0:
                stamp = T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9)
                for side in ("/left", "/right"):
                    img = T[IMAGE](header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="c"),
                                   height=120, width=160, encoding="bgr8", is_bigendian=0,
                                   step=480, data=rng.integers(0, 256, 120 * 480, np.uint8))
                    bag.write(side, t, serialize(img, IMAGE))


def _chunks(mcap: Path) -> list[tuple[int, int]]:
    """(offset, data offset) of each chunk record, by a scan."""
    data = mcap.read_bytes()
    pos, out = 8, []
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06:
            (n,) = struct.unpack_from("<I", data, pos + 9 + 28)
            out.append((pos, pos + 9 + 32 + n + 8))
        if op == 0x02:
            break
        pos += 9 + length
    return out


def _local(_group, _fn, _args):
    return None                                   # no worker: opened in this process


def _read(bag: Path, submit, damage: DamageLog | None = None) -> list[tuple[str, int, bytes]]:
    out = []
    for topic, _mt, t, payload in iter_in_workers(bag, ["/a", "/b", "/left", "/right"], submit,
                                                 image_topics=("/left", "/right"),
                                                 damage=damage):
        if isinstance(payload, mcap_tasks.ImageRef):
            pixels = bytes(payload.data)
            whole = mcap_tasks._CACHE.records(payload.chunk, False)[1]
            payload = bytes(whole[payload.start:payload.start + payload.nbytes])
            assert len(pixels) == 120 * 480 and payload.endswith(pixels)
        out.append((topic, t, bytes(payload)))
    return out


def _serial(bag: Path, damage: DamageLog | None = None) -> list[tuple[str, int, bytes]]:
    return [(t, s, bytes(r)) for t, _m, s, r in iter_messages(
        bag, ["/a", "/b", "/left", "/right"], verify_crc=False, damage=damage)]


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_same_messages_in_the_same_order_whatever_the_groups(tmp_path, monkeypatch,
                                                             compression):
    bag = tmp_path / "bag"
    _write(bag, compression)
    assert worker_readable(bag)
    expected = _serial(bag)
    assert len(expected) == 120
    assert _read(bag, _local) == expected
    monkeypatch.setattr(mcap_tasks, "GROUP_BYTES", 1)   # every chunk its own group
    assert _read(bag, _local) == expected


def test_chunk_refs_are_made_a_few_groups_ahead_not_for_the_whole_file(tmp_path, monkeypatch):
    """A long bag's chunk index is thousands of chunks: its ChunkRefs (about 0.9 kB each) are
    made as their groups are submitted, ``ahead`` groups in advance, in order."""
    import gc
    import weakref

    bag = tmp_path / "bag"
    _write(bag, n=240)
    expected = _serial(bag)
    monkeypatch.setattr(mcap_tasks, "GROUP_BYTES", 1)   # every chunk its own group
    alive: weakref.WeakSet = weakref.WeakSet()
    made = mcap_tasks.ChunkRef.of

    def of(path, info):
        ref = made(path, info)
        alive.add(ref)
        return ref

    monkeypatch.setattr(mcap_tasks.ChunkRef, "of", of)
    # groups opened here (no worker) stay in this process's chunk cache: keep it to one
    monkeypatch.setattr(mcap_tasks._CACHE, "capacity", 1)
    submitted: list[int] = []
    most = 0

    def submit(g, _fn, _args):
        nonlocal most
        submitted.append(g)
        gc.collect()
        most = max(most, len(alive))
        return None

    assert _read(bag, submit) == expected
    n_chunks = len(_chunks(bag / "bag.mcap"))
    assert n_chunks >= 10 and submitted == list(range(n_chunks))
    # ahead = 4: groups g to g + 4 in flight, the group read last and one in the cache
    assert most <= 4 + 3, (most, n_chunks)


def test_worker_processes_open_the_chunks(tmp_path, monkeypatch):
    bag = tmp_path / "bag"
    _write(bag)
    expected = _serial(bag)
    monkeypatch.setattr(mcap_tasks, "GROUP_BYTES", 1)
    owners = set()
    with ProcessPool(2, "os:getpid") as pool:
        pool.wait_ready(60)

        def submit(g, fn, args):
            return pool.submit_to(g, fn, *args)

        got = []
        for topic, _mt, t, p in iter_in_workers(bag, ["/a", "/b", "/left", "/right"], submit,
                                                 image_topics=("/left", "/right")):
            if isinstance(p, mcap_tasks.ImageRef):
                owners.add(p.owner)
                p = bytes(p.data)                 # read here: the chunk opened again
            got.append((topic, t, p))
    assert owners == {0, 1}
    assert [(a, b) for a, b, _ in got] == [(a, b) for a, b, _ in expected]
    for (topic, _t, p), (_a, _b, raw) in zip(got, expected, strict=True):
        assert (raw.endswith(p) and len(p) == 120 * 480) if topic in ("/left", "/right") \
            else p == raw


def test_a_damaged_chunk_is_recorded_as_by_the_serial_reader(tmp_path):
    bag = tmp_path / "bag"
    _write(bag)
    mcap = bag / "bag.mcap"
    off, data_at = _chunks(mcap)[1]
    data = bytearray(mcap.read_bytes())
    noise = np.random.default_rng(1).integers(0, 256, 64, np.uint8).tobytes()
    data[data_at + 2:data_at + 66] = noise
    mcap.write_bytes(bytes(data))
    serial_log, worker_log = DamageLog(), DamageLog()
    expected = _serial(bag, serial_log)
    got = _read(bag, _local, worker_log)
    assert got == expected
    assert len(serial_log) == 1 and worker_log.records == serial_log.records
    assert worker_log.records[0].where == f"chunk at byte {off}"
    assert worker_log.messages_lost > 0


@pytest.mark.parametrize("group_bytes", [1, 1 << 30])
def test_chunks_overlapping_in_time_and_equal_times_merge_as_the_serial_reader(
        tmp_path, monkeypatch, group_bytes):
    import importlib.util

    spec = importlib.util.spec_from_file_location(   # the MCAP writer of the sibling test
        "mcap_chunks_test", Path(__file__).with_name("test_mcap_chunks.py"))
    sibling = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sibling)
    T, _payload, write_mcap = sibling.T0, sibling._payload, sibling.write_mcap

    monkeypatch.setattr(mcap_tasks, "GROUP_BYTES", group_bytes)
    a = [(1, T + k * 10, _payload(f"a{k}")) for k in range(5)]
    b = [(2, T + k * 10 + 5, _payload(f"b{k}")) for k in range(5)] + \
        [(1, T + 40, _payload("tie"))]
    c = [(1, T + 100 + k, _payload(f"c{k}")) for k in range(3)]
    path = tmp_path / "x.mcap"
    write_mcap(path, [a, b, c], compression="zstd")
    expected = [(t, s, bytes(r)) for t, _m, s, r in iter_messages(path, verify_crc=False)]
    got = [(t, s, bytes(p)) for t, _m, s, p in iter_in_workers(path, ["/a", "/b"], _local,
                                                               image_topics=("", ""))]
    assert got == expected and len(got) == 14


def test_a_chunk_leaves_the_cache_once_its_images_are_read(tmp_path):
    """A process holds a decompressed chunk while images of it are still to be read (the
    pairs ahead of it), not until it is the least recently used of 96 MB: each chunk is
    decompressed once, and once all its images are read it is gone."""
    bag = tmp_path / "bag"
    _write(bag, n=120)
    cache = mcap_tasks._CACHE
    cache.clear()
    before = cache.decompressed
    refs = [p for _tp, _mt, _t, p in iter_in_workers(bag, ["/a", "/b", "/left", "/right"],
                                                     _local, image_topics=("/left", "/right"))
            if isinstance(p, mcap_tasks.ImageRef)]
    keys = {(r.chunk.path, r.chunk.chunk_start_offset) for r in refs}
    assert len(refs) == 120 and len(keys) >= 5
    assert keys <= set(cache._chunks)                  # opened, nothing read yet
    for ref in refs:
        assert len(ref.data) == 120 * 480
    assert not keys & set(cache._chunks) and not cache._unread
    assert cache.decompressed - before == len(_chunks(next(bag.glob("*.mcap"))))
    assert refs[0].data.tobytes() == refs[0].data.tobytes()   # read again: decompressed again
    cache.clear()
