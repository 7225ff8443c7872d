"""eye_in_hand.io.bags.chunk_table: the compact chunk index reads as ``rosbags``' parse."""
from __future__ import annotations

import gc
import tracemalloc
from pathlib import Path

import pytest
from rosbags.rosbag2.storage_mcap import ChunkInfo

from eye_in_hand.io.bags import BagWriter, default_typestore, iter_messages, serialize
from eye_in_hand.io.bags import storage_mcap as sm
from eye_in_hand.io.bags.chunk_table import ChunkTable

STRING = "std_msgs/msg/String"
T0 = 1_700_000_000_000_000_000


def _infos(n: int) -> list[ChunkInfo]:
    """Chunk infos as rosbags parses them: 2 or 3 channels, in varying key orders."""
    out = []
    for i in range(n):
        t = T0 + 33_000_000 * i
        at = 43 + 200_000 * i
        ids = (5, 1, 2) if i % 3 else (2, 1)
        mio = {cid: at + 168_000 + 31 * k for k, cid in enumerate(ids)}
        counts = {cid: 1 + (i % 2) * (cid == 1) for cid in sorted(ids)}
        out.append(ChunkInfo(t, t + 3_100_000, at, 167_971, mio, 93,
                             "zstd" if i % 5 else "", 167_918, 1_846_532 + i, counts))
    return out


def test_every_info_is_the_parsed_one_with_its_dicts_in_order():
    infos = _infos(50)
    table = ChunkTable.of(infos)
    assert len(table) == 50 and list(table) == infos
    for got, want in zip(table, infos, strict=True):
        assert type(got) is ChunkInfo
        assert list(got.message_index_offsets) == list(want.message_index_offsets)
        assert list(got.channel_count) == list(want.channel_count)
    assert table[-1] == infos[-1] and table[7] == infos[7] and table[3:9:2] == infos[3:9:2]
    with pytest.raises(IndexError):
        table[50]
    assert table.compressions() == {"zstd", ""}
    a = table[4]
    a.channel_count[99] = 1          # a caller's change to its info stays in its info
    assert table[4] == infos[4]


def test_clear_empties_that_table_only():
    table = ChunkTable.of(_infos(10))
    other = table.copy()
    table.clear()
    assert len(table) == 0 and list(table) == [] and table.compressions() == set()
    assert len(other) == 10 and list(other) == _infos(10)


def test_a_chunk_costs_a_tenth_of_the_parsed_info():
    infos = _infos(5000)
    gc.collect()
    tracemalloc.start()
    try:
        table = ChunkTable.of(infos)
        gc.collect()
        size = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert len(table) == 5000
    assert size / 5000 < 160, size / 5000     # rosbags' ChunkInfo: about 1.4 kB


def _bag(path: Path, n: int = 40) -> None:
    """Strings of about 0.3 MB on /a: a chunk every few messages."""
    store = default_typestore()
    with BagWriter(path, "mcap", "zstd") as bag:
        bag.add_topic("/a", STRING)
        for i in range(n):
            bag.write("/a", T0 + i * 10_000_000,
                      serialize(store.types[STRING](data=f"{i}" * 150_000), STRING))


def test_the_indexed_reader_holds_a_table_that_reads_as_rosbags_parse(tmp_path):
    from rosbags.rosbag2.storage_mcap import McapReader

    path = tmp_path / "bag"
    _bag(path)
    mcap = next(path.glob("*.mcap"))
    plain = McapReader(mcap)
    plain.open()
    parsed = list(plain.chunks)
    plain.close()
    assert len(parsed) > 5
    sm._INDEX_CACHE.clear()
    for _ in range(2):                       # parsed, then from the index cache
        reader = sm._indexed_reader()(mcap)
        reader.open()
        assert isinstance(reader.chunks, ChunkTable) and list(reader.chunks) == parsed
        reader.close()
        assert len(reader.chunks) == 0       # rosbags clears its reader's at close ...
    entry = sm._INDEX_CACHE[str(mcap.resolve())]
    cached = entry[-1]["chunks"]
    assert list(cached) == parsed            # ... and the cache keeps its own
    # and a digest of the summary section it was parsed from, not its bytes
    assert [len(v) for v in entry if isinstance(v, bytes)] == [32]
    got = [bytes(raw) for _t, _m, _s, raw in iter_messages(path, ["/a"])]
    assert len(got) == 40


def test_the_indexed_reader_fills_its_table_as_rosbags_parses(tmp_path, monkeypatch):
    """The chunks go into the table one by one as ``rosbags`` parses the index: its list of
    ``ChunkInfo`` (1.4 kB a chunk, 25 MB on a 10-minute bag, a peak the heap then keeps) is
    never built. A table being built takes chunks; a cleared one, or a copy behind the table
    it was copied from, does not."""
    from rosbags.rosbag2.storage_mcap import McapReader

    import eye_in_hand.io.bags.storage_mcap as sm

    path = tmp_path / "bag"
    _bag(path)
    mcap = next(path.glob("*.mcap"))
    seen: list[tuple[type, int]] = []
    read_index = McapReader.read_index

    def spy(self):
        seen.append((type(self.chunks), len(self.chunks)))
        read_index(self)
        seen.append((type(self.chunks), len(self.chunks)))

    monkeypatch.setattr(McapReader, "read_index", spy)
    sm._INDEX_CACHE.clear()
    reader = sm._indexed_reader()(mcap)
    reader.open()
    n = len(reader.chunks)
    reader.close()
    assert n > 5 and seen == [(ChunkTable, 0), (ChunkTable, n)]

    info = sm._INDEX_CACHE[str(mcap.resolve())][-1]["chunks"][0]
    table = ChunkTable.building()
    table.append(info)
    copy = table.copy()
    table.append(info)
    assert list(table) == [info, info] and list(copy) == [info]   # the copy keeps its length
    with pytest.raises(ValueError, match="only a table being built"):
        copy.append(info)
    table.clear()
    with pytest.raises(ValueError, match="only a table being built"):
        table.append(info)
