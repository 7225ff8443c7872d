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
