"""eye_in_hand.io.bags.formats / storage: the storage formats behind one interface, and what
derives from their registry."""
from __future__ import annotations

from pathlib import Path

import pytest

from eye_in_hand.errors import BagError, InputError
from eye_in_hand.io.bags import STORAGES, BagWriter, bag_info, iter_messages
from eye_in_hand.io.bags.formats import FORMATS, SUFFIXES, format_of
from eye_in_hand.io.bags.storage import StorageFormat
from eye_in_hand.io.bags.storage_mcap import McapFormat
from eye_in_hand.io.bags.storage_sqlite3 import Sqlite3Format

T0 = 1_700_000_000_000_000_000


def test_registry_gives_the_storage_choices_and_suffixes() -> None:
    assert list(FORMATS) == ["mcap", "sqlite3"]
    assert STORAGES == ("mcap", "sqlite3")           # writable ones, the default first
    assert {s: f.name for s, f in SUFFIXES.items()} == {".mcap": "mcap", ".db3": "sqlite3"}
    assert isinstance(FORMATS["mcap"], McapFormat)
    assert isinstance(FORMATS["sqlite3"], Sqlite3Format)


def test_format_of_a_file_a_reader_and_a_directory(tmp_path: Path) -> None:
    assert format_of(tmp_path / "a.mcap") is FORMATS["mcap"]
    assert format_of(str(tmp_path / "a.db3")) is FORMATS["sqlite3"]

    class Reader:
        path = tmp_path / "b.mcap"

    assert format_of(Reader()) is FORMATS["mcap"]
    assert format_of(tmp_path) is None
    assert format_of(tmp_path / "c.bag") is None


def test_the_base_format_leaves_everything_to_rosbags(tmp_path: Path) -> None:
    base = StorageFormat()
    assert not base.writable and base.scan(tmp_path / "x") is None
    assert not base.reads_directly(object()) and not base.mappable(object())
    assert not base.worker_readable(object())
    assert base.read_on(object(), [], None, None, last=None, at_last=0, read={},
                        damage=None, name="x", error=ValueError()) is None
    with pytest.raises(NotImplementedError):
        base.writer_plugin()


@pytest.mark.parametrize("storage", STORAGES)
def test_each_registered_format_round_trips_through_its_file(tmp_path: Path,
                                                             storage: str) -> None:
    fmt = FORMATS[storage]
    with BagWriter(tmp_path / "bag", storage) as bag:
        bag.add_topic("/x", "std_msgs/msg/String")
        for i in range(3):
            bag.write("/x", T0 + i, b"\x00\x01\x00\x00\x02\x00\x00\x00a\x00\x00\x00")
    files = sorted((tmp_path / "bag").glob(f"*{fmt.suffix}"))
    assert len(files) == 1
    assert bag_info(files[0]).storage == storage == bag_info(tmp_path / "bag").storage
    assert [t for _topic, _type, t, _raw in iter_messages(files[0])] == [T0, T0 + 1, T0 + 2]


def test_unknown_storage_and_file_suffix_name_the_registered_ones(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="must be one of mcap, sqlite3"):
        BagWriter(tmp_path / "bag", "bag")
    (tmp_path / "x.bag").write_bytes(b"")
    with pytest.raises(BagError, match=r"nor a \.mcap / \.db3 storage file"):
        bag_info(tmp_path / "x.bag")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"no metadata\.yaml and no \.mcap or \.db3 storage"):
        bag_info(tmp_path / "empty")


def _one_topic_bag(path: Path, topic: str, n: int) -> Path:
    """An MCAP bag directory of ``n`` std_msgs/String messages on ``topic``; its file."""
    with BagWriter(path, "mcap") as bag:
        bag.add_topic(topic, "std_msgs/msg/String")
        for i in range(n):
            bag.write(topic, T0 + i, b"\x00\x01\x00\x00\x02\x00\x00\x00a\x00\x00\x00")
    return next(path.glob("*.mcap"))


def test_an_mcap_file_opened_again_gives_the_same_index_from_the_cache(tmp_path: Path) -> None:
    """The parsed summary of an MCAP file is kept (storage_mcap._INDEX_CACHE): opened again,
    the file has the same connections, owned by the new reader, and its messages read."""
    from eye_in_hand.io.bags import storage_mcap
    from eye_in_hand.io.bags.reading import _OpenBag

    file = _one_topic_bag(tmp_path / "bag", "/x", 5)
    with _OpenBag(file) as first:
        conns = [(c.id, c.topic, c.msgtype, c.msgcount) for c in first.connections()]
    key = str(file.resolve())
    assert key in storage_mcap._INDEX_CACHE
    for _ in range(2):
        with _OpenBag(file) as again:
            storage = again.readers[0].storage
            assert [(c.id, c.topic, c.msgtype, c.msgcount)
                    for c in again.connections()] == conns == [(1, "/x", "std_msgs/msg/String",
                                                               5)]
            assert all(c.owner is storage for c in storage.connections)
            assert storage.chunks and again.readers[0].message_count == 5
    assert [t for _topic, _mt, t, _raw in iter_messages(file)] == [T0 + i for i in range(5)]


def test_an_mcap_file_replaced_at_the_same_path_is_parsed_afresh(tmp_path: Path) -> None:
    """Same path and size, other bytes (a bag written again under the same name): the index
    of the new file, not the one kept from the old."""
    first = _one_topic_bag(tmp_path / "bag", "/a", 3)
    assert list(bag_info(first).topics) == ["/a"]
    size = first.stat().st_size
    import shutil

    shutil.rmtree(tmp_path / "bag")
    second = _one_topic_bag(tmp_path / "bag", "/b", 3)
    assert second == first and second.stat().st_size == size
    assert list(bag_info(second).topics) == ["/b"]
    assert [topic for topic, *_ in iter_messages(second)] == ["/b"] * 3


def _count_parses(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The files whose MCAP index rosbags parses from now on (``McapReader.read_index``)."""
    from rosbags.rosbag2.storage_mcap import McapReader

    parsed: list[str] = []
    real = McapReader.read_index

    def counting(self: McapReader) -> None:
        parsed.append(Path(str(self.path)).parent.name)
        real(self)

    monkeypatch.setattr(McapReader, "read_index", counting)
    return parsed


def test_the_kept_index_is_what_a_second_opening_uses(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    parsed = _count_parses(monkeypatch)
    file = _one_topic_bag(tmp_path / "bag", "/x", 5)
    for _ in range(3):
        assert bag_info(file).topics["/x"].count == 5
    assert parsed == ["bag"]


def test_the_files_used_last_stay_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Least recently used out first: with room for two files, A B A C keeps A and C."""
    from eye_in_hand.io.bags import storage_mcap

    monkeypatch.setattr(storage_mcap, "_INDEX_CACHE_FILES", 2)
    files = {name: _one_topic_bag(tmp_path / name, "/x", 2) for name in "ABC"}
    parsed = _count_parses(monkeypatch)
    for name in "ABACA":
        bag_info(files[name])
    assert parsed == ["A", "B", "C"]


def test_an_mcap_file_without_summary_is_read_afresh_every_time(tmp_path: Path) -> None:
    """A file whose footer points to no summary (as a recording cut before it was finished
    leaves it) is scanned, and the scan's index is never kept: only the summary's bytes are
    compared, and the scan reads the data section."""
    import struct

    from eye_in_hand.io.bags import storage_mcap

    file = _one_topic_bag(tmp_path / "bag", "/x", 4)
    data = file.read_bytes()
    footer = bytearray(data[-37:])
    summary_start = struct.unpack_from("<Q", footer, 9)[0]
    struct.pack_into("<QQI", footer, 9, 0, 0, 0)
    bare = tmp_path / "bare.mcap"
    bare.write_bytes(data[:summary_start] + bytes(footer))
    for _ in range(2):
        assert bag_info(bare).topics["/x"].count == 4
        assert str(bare.resolve()) not in storage_mcap._INDEX_CACHE


@pytest.mark.parametrize("compression", [None, "zstd"])
def test_the_mcap_writers_message_records_are_rosbags_bytes(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch,
                                                           compression: str | None) -> None:
    """The MCAP writer packs each message record's head at once: the file is byte for byte
    the one rosbags' own ``write`` makes (several chunks, several channels, stamps out of
    order, empty and large messages)."""
    from rosbags.rosbag2.storage_mcap import McapWriter

    from eye_in_hand.io.bags.storage_mcap import _crc_writer

    msgs = [("/a" if k % 3 else "/b", 10**18 + (k * 7919) % 1000 * 10**6,
             bytes([0, 1, 0, 0]) + bytes([k % 251]) * ((k * 37) % 5000 if k % 11 else 0))
            for k in range(700)]   # about 1.7 MB: the writer closes a chunk past 1 MiB

    def write(path: Path) -> bytes:
        with BagWriter(path, compression=compression) as bag:
            bag.add_topic("/a", "std_msgs/msg/String")
            bag.add_topic("/b", "std_msgs/msg/String")
            for topic, stamp, raw in msgs:
                bag.write(topic, stamp, raw)
        return (path / f"{path.name}.mcap").read_bytes()

    ours = write(tmp_path / "bag")
    monkeypatch.setattr(_crc_writer(), "write", McapWriter.write)
    upstream = write(tmp_path / "upstream" / "bag")   # the same name (the header has it)
    assert ours == upstream
    assert len(bag_info(tmp_path / "bag").topics) == 2
