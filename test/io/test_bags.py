"""eye_in_hand.io.bags: reading and writing rosbag2 bags without ROS."""
from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from eye_in_hand.errors import BagError, InputError
from eye_in_hand.io.bags import (
    BagWriter,
    OfferedQos,
    bag_info,
    default_typestore,
    deserialize,
    iter_decoded,
    iter_messages,
    require_topics,
    serialize,
    typestore_for,
)

T0 = 1_700_000_000_000_000_000
STRING = "std_msgs/msg/String"


def _string(text: str) -> bytes:
    store = default_typestore()
    return serialize(store.types[STRING](data=text), STRING)


def _write_sample(path: Path, storage: str = "mcap", compression: str | None = None,
                  n: int = 20, seed: int = 0) -> list[tuple[str, int, bytes]]:
    """Two interleaved topics with random stamps; returns (topic, stamp, raw) in time order."""
    rng = np.random.default_rng(seed)
    stamps = T0 + np.sort(rng.choice(10**9, size=n, replace=False)).astype(np.int64)
    written = []
    with BagWriter(path, storage, compression) as bag:
        bag.add_topic("/b/chatter", STRING, qos=[OfferedQos("best_effort", "volatile",
                                                            "keep_last", 5)])
        bag.add_topic("/a/chatter", STRING)
        # write out of order: log time, not write order, decides the reading order
        order = rng.permutation(n)
        for i in order:
            topic = "/a/chatter" if i % 2 else "/b/chatter"
            raw = _string(f"{topic}:{i}")
            bag.write(topic, int(stamps[i]), raw)
            written.append((topic, int(stamps[i]), raw))
    return sorted(written, key=lambda w: w[1])


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("compression", [None, "zstd"])
def test_write_read_round_trip(tmp_path: Path, storage: str, compression: str | None) -> None:
    expected = _write_sample(tmp_path / "bag", storage, compression)
    got = list(iter_messages(tmp_path / "bag"))
    assert [(t, s, r) for t, _m, s, r in got] == expected
    assert all(m == STRING for _t, m, _s, _r in got)
    info = bag_info(tmp_path / "bag")
    assert info.storage == storage
    assert info.version == 9
    assert info.message_count == 20
    assert info.start_ns == expected[0][1] and info.end_ns == expected[-1][1]
    assert info.duration_ns == expected[-1][1] - expected[0][1]
    assert list(info.topics) == ["/a/chatter", "/b/chatter"]
    assert info.topics["/a/chatter"].count == 10 and info.topics["/b/chatter"].count == 10
    assert info.topics["/b/chatter"].offered_qos == (
        OfferedQos("best_effort", "volatile", "keep_last", 5),)
    assert info.topics["/a/chatter"].has_definition
    if storage == "sqlite3" and compression:
        assert (info.compression_format, info.compression_mode) == ("zstd", "message")


def test_topic_and_time_filters(tmp_path: Path) -> None:
    expected = _write_sample(tmp_path / "bag")
    lo, hi = expected[5][1], expected[14][1]
    got = list(iter_messages(tmp_path / "bag", topics=["/a/chatter"], start_ns=lo, end_ns=hi))
    want = [w for w in expected if w[0] == "/a/chatter" and lo <= w[1] <= hi]
    assert [(t, s, r) for t, _m, s, r in got] == want
    assert list(iter_messages(tmp_path / "bag", topics=["/nope"])) == []
    with pytest.raises(InputError, match="before start_ns"):
        list(iter_messages(tmp_path / "bag", start_ns=hi, end_ns=lo))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_time_window_includes_both_ends(tmp_path: Path, storage: str) -> None:
    """start_ns and end_ns are both inclusive: a window from one message's stamp to another's
    holds both, and a window of one stamp holds exactly its message."""
    expected = _write_sample(tmp_path / "bag", storage)
    lo, hi = expected[3][1], expected[11][1]
    got = [(t, s, r) for t, _m, s, r in iter_messages(tmp_path / "bag", start_ns=lo, end_ns=hi)]
    assert got == expected[3:12]
    one = list(iter_messages(tmp_path / "bag", start_ns=hi, end_ns=hi))
    assert [(t, s, r) for t, _m, s, r in one] == [expected[11]]
    assert list(iter_messages(tmp_path / "bag", start_ns=hi + 1, end_ns=hi + 1)) == []


def test_single_mcap_file_and_directory_without_metadata(tmp_path: Path) -> None:
    expected = _write_sample(tmp_path / "bag", "mcap", "zstd")
    mcap = tmp_path / "bag" / "bag.mcap"
    info = bag_info(mcap)
    assert info.version is None and info.storage == "mcap"
    assert info.message_count == 20 and info.topics["/a/chatter"].count == 10
    assert [r for *_x, r in iter_messages(mcap)] == [w[2] for w in expected]
    # a directory whose metadata.yaml is gone is read from its storage files
    (tmp_path / "bag" / "metadata.yaml").unlink()
    assert bag_info(tmp_path / "bag").message_count == 20
    assert [r for *_x, r in iter_messages(tmp_path / "bag")] == [w[2] for w in expected]


def test_split_bag_files_are_merged_in_log_time_order(tmp_path: Path) -> None:
    a = _write_sample(tmp_path / "one", "mcap", seed=1)
    b = _write_sample(tmp_path / "two", "mcap", seed=2)
    loose = tmp_path / "loose"
    loose.mkdir()
    shutil.copy(tmp_path / "one" / "one.mcap", loose / "x_0.mcap")
    shutil.copy(tmp_path / "two" / "two.mcap", loose / "x_1.mcap")
    stamps = [s for _t, _m, s, _r in iter_messages(loose)]
    assert stamps == sorted(w[1] for w in a + b)
    assert bag_info(loose).message_count == 40


# ---- hand-written metadata.yaml of rosbag2 versions 4 to 9 ---------------------------------

_QOS_INT = ("- history: 3\\n  depth: 0\\n  reliability: {rel}\\n  durability: 2\\n"
            "  deadline:\\n    sec: 2147483647\\n    nsec: 4294967295\\n"
            "  lifespan:\\n    sec: 2147483647\\n    nsec: 4294967295\\n  liveliness: 1\\n"
            "  liveliness_lease_duration:\\n    sec: 2147483647\\n    nsec: 4294967295\\n"
            "  avoid_ros_namespace_conventions: false")

_QOS_V9 = """
          - history: keep_last
            depth: 7
            reliability: {rel}
            durability: volatile
            deadline:
              sec: 9223372036
              nsec: 854775807
            lifespan:
              sec: 9223372036
              nsec: 854775807
            liveliness: automatic
            liveliness_lease_duration:
              sec: 9223372036
              nsec: 854775807
            avoid_ros_namespace_conventions: false"""


def _legacy_db3(path: Path, rows: list[tuple[str, int, bytes]]) -> None:
    """A sqlite3 storage file with the Foxy/Galactic schema (no schema table, no definitions)."""
    con = sqlite3.connect(path)
    con.executescript(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,"
        " serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
        "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,"
        " timestamp INTEGER NOT NULL, data BLOB NOT NULL);"
        "CREATE INDEX timestamp_idx ON messages (timestamp ASC);")
    topics = sorted({t for t, _s, _r in rows})
    for i, name in enumerate(topics, 1):
        con.execute("INSERT INTO topics VALUES (?, ?, ?, 'cdr', '')", (i, name, STRING))
    for topic, stamp, raw in rows:
        con.execute("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)",
                    (topics.index(topic) + 1, stamp, raw))
    con.commit()
    con.close()


def _metadata(version: int, file_name: str, rows: list[tuple[str, int, bytes]]) -> str:
    start, end = rows[0][1], rows[-1][1]
    counts = {t: sum(1 for r in rows if r[0] == t) for t in sorted({r[0] for r in rows})}
    topics = ""
    for topic, count in counts.items():
        rel = "2" if topic == "/b/chatter" else "1"
        if version >= 9:
            qos = _QOS_V9.format(rel="best_effort" if rel == "2" else "reliable")
        else:
            qos = ' "' + _QOS_INT.format(rel=rel) + '"'
        topics += f"""
    - topic_metadata:
        name: {topic}
        type: {STRING}
        serialization_format: cdr
        offered_qos_profiles:{qos}"""
        if version >= 7:
            topics += f"""
        type_description_hash: {default_typestore().hash_rihs01(STRING)}"""
        topics += f"""
      message_count: {count}"""
    text = f"""\
rosbag2_bagfile_information:
  version: {version}
  storage_identifier: sqlite3
  duration:
    nanoseconds: {end - start}
  starting_time:
    nanoseconds_since_epoch: {start}
  message_count: {len(rows)}
  topics_with_message_count:{topics}
  compression_format: ""
  compression_mode: ""
  relative_file_paths:
    - {file_name}
"""
    if version >= 5:
        text += f"""\
  files:
    - path: {file_name}
      starting_time:
        nanoseconds_since_epoch: {start}
      duration:
        nanoseconds: {end - start}
      message_count: {len(rows)}
"""
    if version >= 6:
        text += "  custom_data: ~\n"
    if version >= 8:
        text += "  ros_distro: jazzy\n"
    return text


@pytest.mark.parametrize("version", [4, 5, 6, 7, 8, 9])
def test_metadata_versions_4_to_9(tmp_path: Path, version: int) -> None:
    bag = tmp_path / f"v{version}"
    if version <= 6:
        rows = [("/a/chatter" if i % 2 else "/b/chatter", T0 + 1000 * i, _string(f"m{i}"))
                for i in range(8)]
        bag.mkdir()
        _legacy_db3(bag / f"v{version}_0.db3", rows)
    else:  # a current sqlite3 storage file (schema 4 with message definitions)
        rows = [(t, s, r) for t, s, r in _write_sample(tmp_path / "src", "sqlite3", n=8)]
        bag.mkdir()
        shutil.copy(tmp_path / "src" / "src.db3", bag / f"v{version}_0.db3")
    (bag / "metadata.yaml").write_text(_metadata(version, f"v{version}_0.db3", rows))
    info = bag_info(bag)
    assert info.version == version and info.storage == "sqlite3"
    assert info.message_count == 8
    assert info.start_ns == rows[0][1] and info.end_ns == rows[-1][1]
    assert {t: i.count for t, i in info.topics.items()} == {"/a/chatter": 4, "/b/chatter": 4}
    assert info.topics["/b/chatter"].offered_qos[0].reliability == "best_effort"
    assert info.topics["/a/chatter"].offered_qos[0].reliability == "reliable"
    assert info.ros_distro == ("jazzy" if version >= 8 else "")
    got = list(iter_messages(bag))
    assert [(t, s, r) for t, _m, s, r in got] == rows
    store = typestore_for(bag)
    assert deserialize(got[0][3], got[0][1], store).data == deserialize(rows[0][2], STRING).data


# ---- types -------------------------------------------------------------------------------

CUSTOM = "my_robot_msgs/msg/Sample"
CUSTOM_DEF = """\
std_msgs/Header header
float64[3] xyz
string label
my_robot_msgs/Flag[] flags
================================================================================
MSG: my_robot_msgs/Flag
bool on
uint8 level
"""


def test_custom_type_definition_is_stored_and_used(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "bag", "mcap") as bag:
        bag.add_topic("/s", CUSTOM, msgdef=CUSTOM_DEF)
        store = bag.typestore  # the writer's store knows the type now
        Sample = store.types[CUSTOM]
        Flag = store.types["my_robot_msgs/msg/Flag"]
        Header = store.types["std_msgs/msg/Header"]
        Time = store.types["builtin_interfaces/msg/Time"]
        msg = Sample(header=Header(stamp=Time(sec=3, nanosec=4), frame_id="f"),
                     xyz=np.array([1.0, 2.0, 3.0]), label="x",
                     flags=[Flag(on=True, level=7)])
        bag.write("/s", T0, msg)
    (_t, msgtype, _s, raw), = iter_messages(tmp_path / "bag")
    with pytest.raises(BagError, match="not known"):
        deserialize(raw, msgtype)  # Jazzy alone does not know it
    out = deserialize(raw, msgtype, typestore_for(tmp_path / "bag"))
    assert out.label == "x" and out.flags[0].level == 7 and out.header.stamp.sec == 3
    np.testing.assert_array_equal(out.xyz, [1.0, 2.0, 3.0])


def test_unknown_type_without_definition_is_refused(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "bag") as bag:
        with pytest.raises(BagError, match="not in ROS 2 Jazzy"):
            bag.add_topic("/s", CUSTOM)
        with pytest.raises(BagError, match="was not added"):
            bag.write("/s", T0, b"\x00\x01\x00\x00")
        with pytest.raises(InputError, match="non-negative"):
            bag.write("/s", -1, b"")


# ---- errors and validity -----------------------------------------------------------------

def test_writer_leaves_a_valid_bag_when_the_block_raises(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="boom"):
        with BagWriter(tmp_path / "bag", "mcap", "zstd") as bag:
            bag.add_topic("/a", STRING)
            for i in range(5):
                bag.write("/a", T0 + i, _string(str(i)))
            raise RuntimeError("boom")
    assert (tmp_path / "bag" / "metadata.yaml").is_file()
    assert bag_info(tmp_path / "bag").message_count == 5
    assert len(list(iter_messages(tmp_path / "bag"))) == 5
    with pytest.raises(BagError, match="closed"):
        bag.write("/a", T0, _string("late"))


def test_writer_refuses_existing_path_and_bad_options(tmp_path: Path) -> None:
    (tmp_path / "there").mkdir()
    with pytest.raises(BagError, match="exists already"):
        BagWriter(tmp_path / "there")
    with pytest.raises(InputError, match="storage"):
        BagWriter(tmp_path / "x", storage="rosbag1")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="compression"):
        BagWriter(tmp_path / "y", compression="lz4")  # type: ignore[arg-type]


def test_missing_and_corrupt_bags_raise_bag_error_naming_the_path(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="does not exist"):
        bag_info(tmp_path / "nope")
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"this is not an mcap file" * 10)
    with pytest.raises(BagError, match="garbage.mcap"):
        bag_info(garbage)
    _write_sample(tmp_path / "good", "mcap")
    truncated = tmp_path / "truncated.mcap"
    data = (tmp_path / "good" / "good.mcap").read_bytes()
    truncated.write_bytes(data[:200])  # header and schema only: nothing to recover
    with pytest.raises(BagError, match="truncated.mcap"):
        list(iter_messages(truncated))
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="no metadata.yaml"):
        bag_info(tmp_path / "empty")
    _write_sample(tmp_path / "nodb", "sqlite3")
    (tmp_path / "nodb" / "nodb.db3").unlink()
    with pytest.raises(BagError, match="nodb"):
        bag_info(tmp_path / "nodb")
    (tmp_path / "badyaml").mkdir()
    (tmp_path / "badyaml" / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2")
    with pytest.raises(BagError, match="badyaml"):
        bag_info(tmp_path / "badyaml")
    with pytest.raises(BagError, match="neither a bag directory"):
        bag_info(_touch(tmp_path / "notes.txt"))


def _touch(path: Path) -> Path:
    path.write_text("x")
    return path


def test_corrupt_message_data_fails_with_context(tmp_path: Path) -> None:
    _write_sample(tmp_path / "bag", "sqlite3")
    con = sqlite3.connect(tmp_path / "bag" / "bag.db3")
    con.execute("UPDATE messages SET data = X'0001' WHERE timestamp = "
                "(SELECT MIN(timestamp) FROM messages)")
    con.commit()
    con.close()
    (_t, msgtype, _s, raw), *_ = iter_messages(tmp_path / "bag")
    with pytest.raises(BagError, match="cannot decode 2 bytes as std_msgs/msg/String"):
        deserialize(raw, msgtype)


def test_require_topics_names_missing_and_lists_available(tmp_path: Path) -> None:
    _write_sample(tmp_path / "bag")
    info = bag_info(tmp_path / "bag")
    require_topics(info, ["/a/chatter"])
    with pytest.raises(BagError) as err:
        require_topics(info, ["/a/chatter", "/left/image_raw", "/right/image_raw"])
    text = str(err.value)
    assert "lacks topics /left/image_raw, /right/image_raw" in text
    assert "/a/chatter (std_msgs/msg/String, 10)" in text and str(tmp_path / "bag") in text


@pytest.mark.parametrize("compression", [None, "zstd"])
def test_interrupted_mcap_recording_is_read_by_scanning(tmp_path: Path,
                                                        compression: str | None) -> None:
    """A recorder killed hard leaves an MCAP file without summary/footer and no metadata.yaml;
    like ros2 bag, the complete chunks are read by scanning the file."""
    rng = np.random.default_rng(3)
    store = default_typestore()
    sent = []
    with BagWriter(tmp_path / "bag", "mcap", compression) as bag:
        bag.add_topic("/img", "sensor_msgs/msg/Image")
        for i in range(40):  # ~100 kB each: rosbags closes a chunk every 1 MiB
            s = store.types
            msg = s["sensor_msgs/msg/Image"](
                header=s["std_msgs/msg/Header"](
                    stamp=s["builtin_interfaces/msg/Time"](sec=i, nanosec=0), frame_id="c"),
                height=100, width=1000, encoding="mono8", is_bigendian=0, step=1000,
                data=rng.integers(0, 256, 100_000, dtype=np.uint8))
            raw = serialize(msg, "sensor_msgs/msg/Image")
            bag.write("/img", T0 + i * MS_10, raw)
            sent.append(raw)
    mcap = tmp_path / "bag" / "bag.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: int(len(data) * 0.8)])  # killed while writing a chunk
    (tmp_path / "bag" / "metadata.yaml").unlink()
    info = bag_info(tmp_path / "bag")
    n = info.message_count
    assert 10 <= n < 40 and info.topics["/img"].count == n
    assert info.notes and "interrupted" in info.notes[0] and "incomplete record" in info.notes[0]
    got = [r for *_x, r in iter_messages(tmp_path / "bag")]
    assert got == sent[:n]  # a prefix, in order, bytes intact
    assert info.end_ns == T0 + (n - 1) * MS_10
    out = deserialize(got[-1], "sensor_msgs/msg/Image", typestore_for(mcap))
    assert out.header.stamp.sec == n - 1


MS_10 = 10_000_000


def test_rclpy_message_objects_are_refused_with_a_hint(tmp_path: Path) -> None:
    rclpy_msgs = pytest.importorskip("std_msgs.msg")
    with BagWriter(tmp_path / "bag") as bag:
        bag.add_topic("/a", STRING)
        with pytest.raises(BagError, match="serialize_message"):
            bag.write("/a", T0, rclpy_msgs.String(data="x"))


def test_iter_decoded_yields_message_objects(tmp_path: Path) -> None:
    expected = _write_sample(tmp_path / "bag", "sqlite3", n=6)
    got = list(iter_decoded(tmp_path / "bag", topics=["/a/chatter"]))
    want = [(t, st, deserialize(r, STRING).data) for t, st, r in expected if t == "/a/chatter"]
    assert [(t, st, m.data) for t, st, m in got] == want
    con = sqlite3.connect(tmp_path / "bag" / "bag.db3")
    con.execute("UPDATE messages SET data = X'0001'")
    con.commit()
    con.close()
    with pytest.raises(BagError, match=r"topic /\w/chatter at \d+ ns: cannot decode"):
        next(iter_decoded(tmp_path / "bag"))


def _mcap_with_lz4_chunks(path: Path, texts: list[str]) -> None:
    """A ros2 MCAP file whose chunks are lz4-compressed (rosbag2's other chunk compression),
    without summary section (readers must scan), written record by record per the MCAP spec."""
    import struct
    import zlib

    import lz4.frame

    def rec(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    def s(text: str) -> bytes:
        return struct.pack("<I", len(text.encode())) + text.encode()

    out = b"\x89MCAP0\r\n" + rec(0x01, s("ros2") + s("handmade"))
    out += rec(0x03, struct.pack("<H", 1) + s(STRING) + s("ros2msg")
               + struct.pack("<I", 12) + b"string data\n")
    out += rec(0x04, struct.pack("<HH", 1, 1) + s("/chat") + s("cdr") + struct.pack("<I", 0))
    for start in range(0, len(texts), 3):  # three messages per chunk
        records = b""
        for i in range(start, min(start + 3, len(texts))):
            records += rec(0x05, struct.pack("<HIQQ", 1, i, T0 + i, T0 + i) + _string(texts[i]))
        packed = lz4.frame.compress(records)
        out += rec(0x06, struct.pack("<QQQI", T0 + start, T0 + start + 2, len(records),
                                     zlib.crc32(records)) + s("lz4")
                   + struct.pack("<Q", len(packed)) + packed)
    out += rec(0x0F, struct.pack("<I", 0))
    out += rec(0x02, struct.pack("<QQI", 0, 0, 0)) + b"\x89MCAP0\r\n"
    path.write_bytes(out)


def test_lz4_compressed_mcap_chunks(tmp_path: Path) -> None:
    texts = [f"lz4 {i}" for i in range(8)]
    _mcap_with_lz4_chunks(tmp_path / "lz4.mcap", texts)
    info = bag_info(tmp_path / "lz4.mcap")
    assert info.message_count == 8 and info.topics["/chat"].msgtype == STRING
    assert info.notes == ()  # a valid file: read by rosbags, not by the fallback scan
    got = list(iter_decoded(tmp_path / "lz4.mcap"))
    assert [(t, s) for t, s, _m in got] == [("/chat", T0 + i) for i in range(8)]
    assert [m.data for _t, _s, m in got] == texts
    # cut inside the last chunk: the scan recovers the two complete chunks
    data = (tmp_path / "lz4.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: data.rindex(b"lz4") + 10])
    cut = bag_info(tmp_path / "cut.mcap")
    assert cut.message_count == 6 and cut.notes
    assert [m.data for _t, _s, m in iter_decoded(tmp_path / "cut.mcap")] == texts[:6]


def test_a_metadata_yaml_is_parsed_once_per_text(tmp_path: Path, monkeypatch) -> None:
    """A command opens one bag several times; its metadata.yaml is checked by parsing its
    YAML once per text: the same text again takes the kept verdict, an edited file (here
    damaged) is parsed afresh and judged by its new text."""
    import yaml

    from eye_in_hand.io.bags import reading

    bag = tmp_path / "bag"
    _write_sample(bag, n=4)
    reading._parsed_metadata.cache_clear()
    calls = []
    real = yaml.safe_load
    monkeypatch.setattr(yaml, "safe_load", lambda text: calls.append(1) or real(text))
    for _ in range(3):
        assert reading.metadata_problem(bag) is None
        assert len(bag_info(bag).topics) == 2
    assert len(calls) == 1
    (bag / "metadata.yaml").write_text("just: text\n")
    assert reading.metadata_problem(bag) == "has no 'rosbag2_bagfile_information' mapping"
    assert len(calls) == 2


def test_rosbags_parses_a_metadata_yaml_once_per_text(tmp_path: Path) -> None:
    """rosbags' own parse of metadata.yaml (ruamel, 3-5 ms) is kept per text too: reopening
    the bag parses nothing; every open gets its own copy; an edited file is parsed anew."""
    import rosbags.rosbag2.reader as rosbags_reader

    from eye_in_hand.io.bags import reading

    bag = tmp_path / "bag"
    _write_sample(bag, n=4)
    reading._safe_yaml_of.cache_clear()
    assert bag_info(bag).topics["/a/chatter"].count == 2
    first = reading._safe_yaml_of.cache_info()
    assert first.misses >= 1
    for _ in range(3):
        assert bag_info(bag).topics["/a/chatter"].count == 2
    again = reading._safe_yaml_of.cache_info()
    assert again.misses == first.misses and again.hits >= first.hits + 3
    # the reader owns what it gets: a change to one parse is not seen by the next
    text = (bag / "metadata.yaml").read_text()
    one = rosbags_reader.YAML(typ="safe").load(text)
    one["rosbag2_bagfile_information"]["message_count"] = -1
    assert rosbags_reader.YAML(typ="safe").load(text)["rosbag2_bagfile_information"][
        "message_count"] == 4
    (bag / "metadata.yaml").write_text(text.replace("message_count: 2", "message_count: 3"))
    assert bag_info(bag).topics["/a/chatter"].count == 3
    assert reading._safe_yaml_of.cache_info().misses == first.misses + 1


def test_a_types_definition_is_rosbags_own_and_made_once_per_store() -> None:
    from rosbags.typesys import Stores, get_typestore

    from eye_in_hand.io.bags.writing import type_definition

    store = get_typestore(Stores.ROS2_JAZZY)
    t = "visualization_msgs/msg/MarkerArray"
    want = (store.generate_msgdef(t, ros_version=2)[0], store.hash_rihs01(t))
    assert type_definition(store, t) == want and want[1].startswith("RIHS01_")
    calls = []
    store.generate_msgdef = lambda *a, **k: calls.append(a)   # type: ignore[method-assign]
    assert type_definition(store, t) == want and calls == []
    other = get_typestore(Stores.ROS2_JAZZY)      # another store: its own
    assert type_definition(other, t) == want
