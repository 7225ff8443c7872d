"""eye_in_hand.io.bags.mcap_chunks: the memory-mapped MCAP reader behind ``iter_messages``.

The files here are written record by record (MCAP spec, https://mcap.dev/spec) so that the
cases real writers produce but ``rosbags``' writer does not are covered: chunk CRCs, lz4 chunks,
chunks that overlap in time, and files without message indexes.
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.errors import BagError
from eye_in_hand.io.bags import default_typestore, iter_messages, serialize

STRING = "std_msgs/msg/String"
T0 = 1_700_000_000_000_000_000
MAGIC = b"\x89MCAP0\r\n"


def _s(text: str | bytes) -> bytes:
    raw = text.encode() if isinstance(text, str) else text
    return struct.pack("<I", len(raw)) + raw


def _rec(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _payload(text: str) -> bytes:
    return serialize(default_typestore().types[STRING](data=text), STRING)


def write_mcap(path: Path, chunks: list[list[tuple[int, int, bytes]]], *,
               compression: str = "", crc: bool = False, message_index: bool = True) -> None:
    """An MCAP file with topics /a (channel 1) and /b (channel 2) of std_msgs/String.

    ``chunks``: per chunk, its messages as (channel id, log time, data), in record order.
    """
    schema = _rec(0x03, struct.pack("<H", 1) + _s(STRING) + _s("ros2msg") + _s("string data"))
    channels = b"".join(_rec(0x04, struct.pack("<HH", cid, 1) + _s(topic) + _s("cdr")
                             + struct.pack("<I", 0))
                        for cid, topic in ((1, "/a"), (2, "/b")))
    out = bytearray(MAGIC + _rec(0x01, _s("ros2") + _s("test")) + schema + channels)
    indexes = []
    counts = {1: 0, 2: 0}
    for msgs in chunks:
        records, offsets = bytearray(), {1: [], 2: []}
        for seq, (cid, t, data) in enumerate(msgs):
            offsets[cid].append((t, len(records)))
            records += _rec(0x05, struct.pack("<HIQQ", cid, seq, t, t) + data)
            counts[cid] += 1
        if compression == "zstd":
            from backports import zstd
            packed = zstd.compress(bytes(records))
        elif compression == "lz4":
            import lz4.frame
            packed = lz4.frame.compress(bytes(records))
        else:
            packed = bytes(records)
        times = [t for _c, t, _d in msgs]
        start, end = min(times), max(times)
        chunk_at = len(out)
        out += _rec(0x06, struct.pack("<QQQI", start, end, len(records),
                                      zlib.crc32(records) if crc else 0)
                    + _s(compression) + struct.pack("<Q", len(packed)) + packed)
        chunk_len = len(out) - chunk_at
        index_offsets = bytearray()
        if message_index:
            for cid, entries in offsets.items():
                if entries:
                    index_offsets += struct.pack("<HQ", cid, len(out))
                    out += _rec(0x07, struct.pack("<HI", cid, 16 * len(entries))
                                + b"".join(struct.pack("<QQ", t, o) for t, o in entries))
        index_len = len(out) - chunk_at - chunk_len
        indexes.append(struct.pack("<QQQQ", start, end, chunk_at, chunk_len)
                       + struct.pack("<I", len(index_offsets)) + index_offsets
                       + struct.pack("<Q", index_len) + _s(compression)
                       + struct.pack("<QQ", len(packed), len(records)))
    out += _rec(0x0F, struct.pack("<I", 0))
    summary_at = len(out)
    out += schema + channels
    for body in indexes:
        out += _rec(0x08, body)
    all_times = [t for msgs in chunks for _c, t, _d in msgs]
    stats = struct.pack("<QHIIIIQQ", len(all_times), 1, 2, 0, 0, len(chunks), min(all_times),
                        max(all_times))
    per_channel = b"".join(struct.pack("<HQ", cid, n) for cid, n in counts.items())
    out += _rec(0x0B, stats + struct.pack("<I", len(per_channel)) + per_channel)
    out += _rec(0x02, struct.pack("<QQI", summary_at, 0, 0)) + MAGIC
    path.write_bytes(bytes(out))


def _chunks(n_chunks: int = 3, per_chunk: int = 6, seed: int = 0,
            ) -> list[list[tuple[int, int, bytes]]]:
    rng = np.random.default_rng(seed)
    out, t = [], T0
    for k in range(n_chunks):
        msgs = []
        for i in range(per_chunk):
            t += int(rng.integers(1, 1000))
            msgs.append((1 + (i % 2), t, _payload(f"chunk {k} message {i}")))
        rng.shuffle(msgs)                    # records need not be in time order inside a chunk
        out.append(msgs)
    return out


def _expected(chunks: list[list[tuple[int, int, bytes]]],
              topics: tuple[str, ...] = ("/a", "/b")) -> list[tuple[str, int, bytes]]:
    names = {1: "/a", 2: "/b"}
    flat = [(t, names[c], d) for msgs in chunks for c, t, d in msgs if names[c] in topics]
    return [(topic, t, d) for t, topic, d in sorted(flat, key=lambda m: m[0])]


def _read(path: Path, **kw: object) -> list[tuple[str, int, bytes]]:
    return [(topic, t, bytes(raw)) for topic, _mt, t, raw in iter_messages(path, **kw)]


@pytest.mark.parametrize("compression", ["", "zstd", "lz4"])
@pytest.mark.parametrize("views", [False, True])
def test_reads_every_message_in_log_time_order(tmp_path: Path, compression: str,
                                               views: bool) -> None:
    chunks = _chunks()
    path = tmp_path / "x.mcap"
    write_mcap(path, chunks, compression=compression)
    got = list(iter_messages(path, views=views))
    assert [(topic, t, bytes(raw)) for topic, _mt, t, raw in got] == _expected(chunks)
    assert all(mt == STRING for _tp, mt, _t, _r in got)
    assert all(isinstance(raw, memoryview if views else bytes) for *_x, raw in got)


def test_topic_filter_and_time_window(tmp_path: Path) -> None:
    chunks = _chunks(n_chunks=4)
    path = tmp_path / "x.mcap"
    write_mcap(path, chunks)
    every = _expected(chunks)
    lo, hi = every[5][1], every[17][1]
    assert _read(path, topics=["/b"]) == _expected(chunks, ("/b",))
    assert _read(path, start_ns=lo, end_ns=hi) == [m for m in every if lo <= m[1] <= hi]


def test_chunks_that_overlap_in_time_are_merged(tmp_path: Path) -> None:
    a = [(1, T0 + k * 10, _payload(f"a{k}")) for k in range(5)]
    b = [(2, T0 + k * 10 + 5, _payload(f"b{k}")) for k in range(5)]
    c = [(1, T0 + 100 + k, _payload(f"c{k}")) for k in range(3)]
    path = tmp_path / "x.mcap"
    write_mcap(path, [a, b, c], compression="zstd")
    got = _read(path)
    assert got == _expected([a, b, c])
    assert [t for _tp, t, _d in got] == sorted(t for _c, t, _d in a + b + c)


def test_equal_log_times_keep_file_order(tmp_path: Path) -> None:
    a = [(1, T0 + 10, _payload("first")), (2, T0 + 10, _payload("second"))]
    b = [(1, T0 + 10, _payload("third")), (2, T0 + 20, _payload("fourth"))]
    path = tmp_path / "x.mcap"
    write_mcap(path, [a, b])
    assert [d for _tp, _t, d in _read(path)] == [_payload(x) for x in
                                                ("first", "second", "third", "fourth")]


def test_file_without_message_indexes_is_read_whole(tmp_path: Path) -> None:
    chunks = _chunks()
    path = tmp_path / "x.mcap"
    write_mcap(path, chunks, message_index=False)
    assert _read(path, topics=["/a"]) == _expected(chunks, ("/a",))


def test_crc_is_checked_when_asked(tmp_path: Path) -> None:
    chunks = _chunks(n_chunks=2)
    path = tmp_path / "x.mcap"
    write_mcap(path, chunks, crc=True)
    assert _read(path) == _expected(chunks)
    data = bytearray(path.read_bytes())
    at = data.index(b"chunk 1 message 3")
    data[at] ^= 0x20                                       # "Chunk 1 message 3"
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"x\.mcap.*chunk at byte \d+: CRC mismatch"):
        _read(path)
    got = _read(path, verify_crc=False)                    # read as stored, corruption and all
    assert len(got) == 12 and any(b"Chunk 1 message 3" in d for _tp, _t, d in got)


def test_corrupt_compressed_chunk_is_a_bag_error(tmp_path: Path) -> None:
    chunks = _chunks(n_chunks=3)
    path = tmp_path / "x.mcap"
    write_mcap(path, chunks, compression="zstd")
    data = bytearray(path.read_bytes())
    second = [i for i in range(len(data)) if data[i:i + 4] == b"\x28\xb5\x2f\xfd"][1]
    data[second:second + 4] = b"XXXX"                      # the 2nd chunk's zstd frame magic
    path.write_bytes(bytes(data))
    got = []
    with pytest.raises(BagError, match=r"cannot read bag .*x\.mcap after message 6"):
        for topic, _mt, t, raw in iter_messages(path):
            got.append((topic, t, bytes(raw)))
    assert got == _expected(chunks)[:6]                    # what came before is delivered


def test_a_chunk_that_does_not_decompress_is_recorded_as_itself(tmp_path: Path) -> None:
    """With a damage log the bag is read on: the second chunk, whose zstd frame does not
    decompress, is the one recorded (its byte offset, its time range, its six messages), and
    the first and third chunks' messages are delivered."""
    from eye_in_hand.io.bags import DamageLog

    chunks = _chunks(n_chunks=3)
    path = tmp_path / "x.mcap"
    write_mcap(path, chunks, compression="zstd")
    data = bytearray(path.read_bytes())
    frames = [i for i in range(len(data)) if data[i:i + 4] == b"\x28\xb5\x2f\xfd"]
    data[frames[1]:frames[1] + 4] = b"XXXX"
    path.write_bytes(bytes(data))
    log = DamageLog()
    got = _read(path, damage=log)
    assert got == _expected([chunks[0], chunks[2]])
    (damage,) = log.records
    where = damage.where.removeprefix("chunk at byte ")
    assert where.isdigit() and frames[0] < int(where) < frames[1], (damage, frames)
    times = [t for _c, t, _d in chunks[1]]
    assert (damage.start_ns, damage.end_ns, damage.messages) == (min(times), max(times), 6)


def test_views_outlive_the_iteration(tmp_path: Path) -> None:
    chunks = _chunks()
    path = tmp_path / "x.mcap"
    write_mcap(path, chunks)
    views = [raw for *_x, raw in iter_messages(path, views=True)]
    arrays = [np.frombuffer(v, np.uint8) for v in views]
    assert [a.tobytes() for a in arrays] == [d for _tp, _t, d in _expected(chunks)]
    assert all(v.readonly for v in views)


def test_zstd_chunks_decompress_with_their_size(tmp_path: Path) -> None:
    from eye_in_hand.io.bags import mcap_chunks

    chunks = _chunks()
    write_mcap(tmp_path / "x.mcap", chunks, compression="zstd")
    assert _read(tmp_path / "x.mcap") == _expected(chunks)
    try:
        from compression import zstd  # type: ignore[import-not-found]
    except ImportError:
        from backports import zstd  # type: ignore[no-redef]
    fn = mcap_chunks._decompressor("zstd")
    data = zstd.compress(b"0123456789" * 1000)
    assert bytes(fn(data, 10_000)) == b"0123456789" * 1000
    with pytest.raises(ValueError, match="more than the 100 bytes"):
        fn(data, 100)               # a size smaller than the data is never cut silently


@pytest.mark.parametrize("compression", ["", "zstd"])
def test_a_chunk_read_leaves_no_record_behind(tmp_path: Path, compression: str) -> None:
    """A long bag has tens of thousands of chunks: each one's record (:class:`_Chunk`) goes
    once it has been read, so that what the reader holds does not grow with the bag."""
    import gc

    from eye_in_hand.io.bags.mcap_chunks import _Chunk

    chunks = _chunks(n_chunks=40, per_chunk=2)
    path = tmp_path / "x.mcap"
    write_mcap(path, chunks, compression=compression)

    def alive() -> int:
        gc.collect()
        return sum(isinstance(o, _Chunk) for o in gc.get_objects())

    seen = []
    got = []
    for k, (topic, _mt, t, raw) in enumerate(iter_messages(path)):
        got.append((topic, t, bytes(raw)))
        if k in (4, 40, 70):
            seen.append(alive())
    assert got == _expected(chunks)
    assert seen[0] <= 40 and seen[1] <= 22 and seen[2] <= 7, seen


def test_reading_holds_no_chunk_info_per_chunk(tmp_path: Path) -> None:
    """Reading checks every chunk's record up front, but keeps only what it reads of each
    (offset, length, times, its header fields and a view of its data): not the index's
    ``ChunkInfo`` with its two dicts (1.4 kB a chunk, 25 MB for the 18000 chunks of a
    10-minute bag, held while a camera_info was looked up)."""
    import gc
    import tracemalloc

    n = 3000
    chunks = [[(1, T0 + 1000 * k, _payload("x"))] for k in range(n)]
    path = tmp_path / "many.mcap"
    write_mcap(path, chunks)
    assert len(_read(path)) == n                   # its index parsed and kept (cache)
    gc.collect()
    tracemalloc.start()
    try:
        first = next(iter_messages(path))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert first[2] == T0
    assert peak / n < 800, peak / n
