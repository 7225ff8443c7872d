"""Damaged bags: CRCs written, damage skipped, counted and named; Jazzy decode fallback."""
from __future__ import annotations

import sqlite3
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.errors import BagError
from eye_in_hand.io.bags import (
    BagWriter,
    DamageLog,
    bag_info,
    default_typestore,
    deserialize,
    iter_decoded,
    iter_messages,
    serialize,
    typestore_for,
)

T0 = 1_700_000_000_000_000_000
MS = 1_000_000
STRING = "std_msgs/msg/String"


def _write(path: Path, storage: str = "mcap", compression: str | None = None,
           n: int = 60, size: int = 100_000) -> list[tuple[str, int, bytes]]:
    """``n`` messages of ``size`` bytes on two topics, 10 ms apart: several 1 MiB chunks."""
    store = default_typestore()
    rng = np.random.default_rng(5)
    out = []
    with BagWriter(path, storage, compression) as bag:  # type: ignore[arg-type]
        bag.add_topic("/a", STRING)
        bag.add_topic("/b", STRING)
        for i in range(n):
            topic = "/a" if i % 3 else "/b"
            text = f"{i}:" + rng.integers(97, 103, size, dtype=np.uint8).tobytes().decode()
            raw = serialize(store.types[STRING](data=text), STRING)
            bag.write(topic, T0 + i * 10 * MS, raw)
            out.append((topic, T0 + i * 10 * MS, raw))
    return out


def _chunks(mcap: Path) -> list[tuple[int, int, int, int]]:
    """(offset, record length, uncompressed crc, data offset) of each chunk record, by a scan."""
    data = mcap.read_bytes()
    pos, out = 8, []
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x06:
            body = pos + 9
            crc = struct.unpack_from("<I", data, body + 24)[0]
            (n,) = struct.unpack_from("<I", data, body + 28)
            out.append((pos, 9 + length, crc, body + 32 + n + 8))
        if op == 0x02:
            break
        pos += 9 + length
    return out


def _damage(mcap: Path, at: int, n: int = 64, seed: int = 1) -> None:
    data = bytearray(mcap.read_bytes())
    data[at:at + n] = np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()
    mcap.write_bytes(bytes(data))


@pytest.mark.parametrize("compression", [None, "zstd"])
def test_written_mcap_files_carry_chunk_data_and_summary_crcs(tmp_path: Path,
                                                               compression: str | None) -> None:
    _write(tmp_path / "bag", compression=compression)
    mcap = tmp_path / "bag" / "bag.mcap"
    data = mcap.read_bytes()
    chunks = _chunks(mcap)
    assert len(chunks) >= 4
    for _off, _len, crc, _d in chunks:
        assert crc != 0
    # the chunk CRC is the CRC-32 of the uncompressed records (checked by the reader)
    assert len(list(iter_messages(tmp_path / "bag", verify_crc=True))) == 60
    summary_start = struct.unpack_from("<Q", data, len(data) - 37 + 9)[0]
    data_end = summary_start - 13
    assert data[data_end] == 0x0F
    assert struct.unpack_from("<I", data, data_end + 9)[0] == zlib.crc32(data[:data_end])
    footer = len(data) - 37
    assert struct.unpack_from("<I", data, footer + 25)[0] == \
        zlib.crc32(data[summary_start:footer + 25])
    assert bag_info(tmp_path / "bag").ros_distro == "jazzy"
    assert "ros_distro: jazzy" in (tmp_path / "bag" / "metadata.yaml").read_text()


def test_sqlite3_bags_say_jazzy_too(tmp_path: Path) -> None:
    _write(tmp_path / "bag", "sqlite3", n=5, size=10)
    assert bag_info(tmp_path / "bag").ros_distro == "jazzy"


@pytest.mark.parametrize("name", ["calibration", "localization"])
def test_bundled_bags_say_jazzy(name: str) -> None:
    """The bundled bags (docs/bags.md: ``ros_distro: jazzy``), in metadata.yaml and in the
    metadata copy inside the MCAP file, which ``ros2 bag reindex`` reads."""
    bag = Path(__file__).resolve().parents[2] / "bags" / name
    assert bag_info(bag).ros_distro == "jazzy"
    data = (bag / f"{name}.mcap").read_bytes()
    assert b"ros_distro: jazzy\n" in data and b"ros_distro: rosbags" not in data
    assert sum(1 for _ in iter_messages(bag)) == bag_info(bag).message_count


def test_verify_crc_names_the_corrupt_chunk(tmp_path: Path) -> None:
    sent = _write(tmp_path / "bag")
    mcap = tmp_path / "bag" / "bag.mcap"
    off, _len, _crc, data_at = _chunks(mcap)[2]
    raw = bytearray(mcap.read_bytes())
    raw[data_at + 5000] ^= 0x01           # one bit, inside a message's text
    mcap.write_bytes(bytes(raw))
    # without the check the flipped bit passes unnoticed
    assert len(list(iter_messages(tmp_path / "bag", verify_crc=False))) == len(sent)
    with pytest.raises(BagError, match=f"chunk at byte {off}: CRC mismatch"):
        list(iter_messages(tmp_path / "bag", verify_crc=True))
    log = DamageLog()
    got = list(iter_messages(tmp_path / "bag", verify_crc=True, damage=log))
    assert len(log) == 1
    d = log.records[0]
    assert d.where == f"chunk at byte {off}" and "CRC mismatch" in d.reason
    assert d.messages == len(sent) - len(got) > 0
    assert sum(d.topics.values()) == d.messages and set(d.topics) <= {"/a", "/b"}
    lost = {(t, s) for t, s, _r in sent} - {(t, s) for t, _m, s, _r in got}
    assert min(s for _t, s in lost) >= d.start_ns and max(s for _t, s in lost) <= d.end_ns
    assert f"chunk at byte {off}" in log.lines()[0] and "bag.mcap" in log.lines()[0]


@pytest.mark.parametrize("compression", [None, "zstd"])
def test_random_bytes_in_one_chunk_cost_only_that_chunk(tmp_path: Path,
                                                        compression: str | None) -> None:
    sent = _write(tmp_path / "bag", compression=compression)
    mcap = tmp_path / "bag" / "bag.mcap"
    chunks = _chunks(mcap)
    off, length, _crc, data_at = chunks[1]
    # over the first record headers of the chunk's data: the records stop making sense
    _damage(mcap, data_at + 2, 64)
    with pytest.raises(BagError, match=f"chunk at byte {off}"):
        list(iter_messages(tmp_path / "bag"))
    log = DamageLog()
    got = [(t, s, r) for t, _m, s, r in iter_messages(tmp_path / "bag", damage=log)]
    assert len(log) == 1 and log.records[0].where == f"chunk at byte {off}"
    assert log.messages_lost == len(sent) - len(got)
    assert 0 < log.messages_lost < len(sent) // 2
    assert set(got) <= set(sent)                 # nothing invented
    # every message outside the damaged chunk's time range came through intact
    d = log.records[0]
    outside = [m for m in sent if not d.start_ns <= m[1] <= d.end_ns]
    assert set(outside) <= set(got)
    assert log.to_dict()["by_topic"] == {t: n for t, n in sorted(d.topics.items())}


def test_truncated_file_in_a_bag_directory_loses_only_its_tail(tmp_path: Path) -> None:
    sent = _write(tmp_path / "bag", compression="zstd")
    mcap = tmp_path / "bag" / "bag.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: int(len(data) * 0.7)])   # metadata.yaml stays
    info = bag_info(tmp_path / "bag")
    assert info.notes and "truncated" in info.notes[0]
    log = DamageLog()
    got = [(t, s, r) for t, _m, s, r in iter_messages(tmp_path / "bag", damage=log)]
    assert 0 < len(got) < len(sent) and got == [m for m in sent[:len(got)]]
    assert len(log) == 1 and log.records[0].where.startswith("file tail from byte")
    # metadata.yaml has the per-topic counts: the lost tail is counted exactly
    lost = sent[len(got):]
    assert log.records[0].messages == len(lost) and log.unknown == 0
    assert dict(log.records[0].topics) == {t: sum(1 for m in lost if m[0] == t)
                                           for t in {m[0] for m in lost}}
    assert log.records[0].start_ns == lost[0][1]          # from the cut
    assert "counts from metadata.yaml" in log.records[0].describe()
    # a bare file has no counts: unknown, and said so
    bare = tmp_path / "bare.mcap"
    bare.write_bytes(mcap.read_bytes())
    log = DamageLog()
    assert len(list(iter_messages(bare, damage=log))) == len(got)
    assert log.records[0].messages is None and log.unknown == 1
    assert "unknown number" in log.records[0].describe()


def test_bad_chunk_in_a_file_without_summary_is_skipped_by_the_scan(tmp_path: Path) -> None:
    sent = _write(tmp_path / "bag", compression="zstd")
    mcap = tmp_path / "bag" / "bag.mcap"
    off, _length, _crc, data_at = _chunks(mcap)[1]
    _damage(mcap, data_at + 100)
    data = mcap.read_bytes()
    mcap.write_bytes(data[: int(len(data) * 0.9)])
    log = DamageLog()
    got = [(t, s, r) for t, _m, s, r in iter_messages(tmp_path / "bag", damage=log)]
    wheres = [d.where for d in log.records]
    assert f"chunk at byte {off}" in wheres and any(w.startswith("file tail") for w in wheres)
    chunk = next(d for d in log.records if d.where == f"chunk at byte {off}")
    after = [m for m in sent if m[1] > chunk.end_ns and m in got]
    assert after, "messages after the damaged chunk are read"


def test_sqlite3_row_that_does_not_decode_is_a_damaged_message(tmp_path: Path) -> None:
    sent = _write(tmp_path / "bag", "sqlite3", n=10, size=20)
    con = sqlite3.connect(tmp_path / "bag" / "bag.db3")
    con.execute("UPDATE messages SET data = X'000100000500' WHERE timestamp = ?",
                (sent[4][1],))
    con.commit()
    con.close()
    with pytest.raises(BagError, match=f"topic {sent[4][0]} at {sent[4][1]} ns"):
        list(iter_decoded(tmp_path / "bag"))
    log = DamageLog()
    got = list(iter_decoded(tmp_path / "bag", damage=log))
    assert len(got) == 9
    assert log.by_topic() == {sent[4][0]: 1}
    d = log.records[0]
    assert d.where == "message" and d.start_ns == sent[4][1] and d.messages == 1


def test_per_message_zstd_that_does_not_decompress_is_a_damaged_message(tmp_path: Path) -> None:
    sent = _write(tmp_path / "bag", "sqlite3", "zstd", n=10, size=20)
    con = sqlite3.connect(tmp_path / "bag" / "bag.db3")
    con.execute("UPDATE messages SET data = X'28b52ffd00ff' WHERE timestamp = ?",
                (sent[7][1],))
    con.commit()
    con.close()
    log = DamageLog()
    got = list(iter_messages(tmp_path / "bag", damage=log))
    assert len(got) == 9 and log.by_topic() == {sent[7][0]: 1}
    assert "decompress" in log.records[0].reason


OLD_LOG = """\
# an old definition with a field the recorded messages do not have
builtin_interfaces/Time stamp
uint8 level
string name
string msg
string file
string function
uint32 line
string node_namespace
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


def test_stored_definition_that_fails_falls_back_to_jazzy(tmp_path: Path) -> None:
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_typestore

    from eye_in_hand.io.bags import types_from_definition

    jazzy = default_typestore()
    old = get_typestore(Stores.ROS2_JAZZY)
    old.fielddefs.pop("rcl_interfaces/msg/Log", None)
    old.types.pop("rcl_interfaces/msg/Log", None)
    old.register(types_from_definition("rcl_interfaces/msg/Log",
                                        MessageDefinitionFormat.MSG, OLD_LOG))
    T = jazzy.types
    log_type = "rcl_interfaces/msg/Log"
    raw = serialize(T[log_type](stamp=T["builtin_interfaces/msg/Time"](sec=3, nanosec=0),
                                level=20, name="node", msg="hello", file="f.py",
                                function="main", line=7), log_type)
    with BagWriter(tmp_path / "bag", typestore=old) as bag:
        bag.add_topic("/rosout", log_type)
        bag.write("/rosout", T0, raw)
    store = typestore_for(tmp_path / "bag")
    assert "node_namespace" in [f for f, _ in store.fielddefs[log_type][1]]  # stored def used
    # any error: which one rosbags raises is not its API, and io.bags.decoding catches any
    with pytest.raises(Exception):  # noqa: B017
        store.deserialize_cdr(raw, log_type)            # the stored definition fails
    msg = deserialize(raw, log_type, store)
    assert (msg.msg, msg.line, msg.name) == ("hello", 7, "node")
    log = DamageLog()
    (topic, _t, decoded), = list(iter_decoded(tmp_path / "bag", damage=log))
    assert topic == "/rosout" and decoded.msg == "hello" and not log


def test_messages_before_a_bad_record_are_kept(tmp_path: Path) -> None:
    sent = _write(tmp_path / "bag", n=60, size=100_000)   # about 10 messages per chunk
    mcap = tmp_path / "bag" / "bag.mcap"
    off, _length, _crc, data_at = _chunks(mcap)[2]
    data = mcap.read_bytes()
    pos, starts = data_at, []                  # record starts inside the (uncompressed) chunk
    for _ in range(4):
        starts.append(pos)
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    assert all(data[s] == 0x05 for s in starts)          # messages
    raw = bytearray(data)
    raw[starts[3] + 1:starts[3] + 9] = (2**40).to_bytes(8, "little")   # a length past the end
    mcap.write_bytes(bytes(raw))
    log = DamageLog()
    # with the CRC checked the whole chunk is refused; without it, the records are parsed
    got = [(t, s, r) for t, _m, s, r in iter_messages(tmp_path / "bag", damage=log,
                                                      verify_crc=False)]
    (d,) = log.records
    assert d.where == f"chunk at byte {off}" and "longer than the chunk" in d.reason
    in_chunk = [m for m in sent if d.start_ns <= m[1] <= d.end_ns]
    assert [m for m in in_chunk if m in got] == in_chunk[:3]     # the three before it
    assert d.messages == len(in_chunk) - 3 == len(sent) - len(got)
