"""Bag tools benchmark: write/read throughput per storage, and playback timing accuracy.

Run: ``.venv/bin/python benchmarks/bench_bags.py`` (about 20 s; uses a temporary directory).

Figures printed:
* write and read throughput (MB/s, messages/s) of 640x480 mono8 images for mcap and sqlite3,
  with and without zstd; read as ``bytes``, and as views (``iter_messages(views=True)``,
  zero-copy for uncompressed MCAP);
* playback timing: for a 100 Hz topic played in-process, the delay between each message's due
  time (start + (t - t_first) / rate) and its arrival at a subscriber (median, 95th percentile,
  maximum), at rate 1 and rate 4;
* recording: 200 images of 640x480 mono8 published back to back in the same process, written,
  dropped, and end-to-end MB/s, for mcap and sqlite3;
* zstd chunk decompression (GB of output per CPU-second, best and median of 5 passes over the
  first 30 chunks) of the bundled localization bag (rendered without noise) and, when
  ``benchmarks/bench_localization.py`` has made it, of its 1280x720 bag with sensor noise:
  without the uncompressed size (``backports.zstd.decompress``), with it
  (``backports.zstd.ZstdDecompressor(max_length=size)``), and the function
  ``eye_in_hand.io.bags.mcap_chunks`` uses.

Run ``--zstd`` for the decompression figures only.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from eye_in_hand.io.bags import BagWriter, default_typestore, iter_messages, serialize

T0 = 1_700_000_000_000_000_000


def _image_bytes(rng: np.random.Generator, n: int) -> list[bytes]:
    s = default_typestore().types
    out = []
    base = rng.integers(0, 256, size=(480, 640), dtype=np.uint8)
    for i in range(n):
        data = np.roll(base, i, axis=1).ravel()
        msg = s["sensor_msgs/msg/Image"](
            header=s["std_msgs/msg/Header"](
                stamp=s["builtin_interfaces/msg/Time"](sec=i, nanosec=0), frame_id="cam"),
            height=480, width=640, encoding="mono8", is_bigendian=0, step=640, data=data)
        out.append(serialize(msg, "sensor_msgs/msg/Image"))
    return out


def bench_io(tmp: Path) -> None:
    rng = np.random.default_rng(0)
    msgs = _image_bytes(rng, 100)
    total_mb = sum(len(m) for m in msgs) / 1e6
    print(f"throughput: {len(msgs)} images of 640x480 mono8 ({total_mb:.1f} MB)")
    for storage in ("mcap", "sqlite3"):
        for compression in (None, "zstd"):
            path = tmp / f"io_{storage}_{compression}"
            t = time.perf_counter()
            with BagWriter(path, storage, compression) as bag:  # type: ignore[arg-type]
                bag.add_topic("/img", "sensor_msgs/msg/Image")
                for i, raw in enumerate(msgs):
                    bag.write("/img", T0 + i * 33_000_000, raw)
            t_write = time.perf_counter() - t
            t = time.perf_counter()
            n = sum(1 for _ in iter_messages(path))
            t_read = time.perf_counter() - t
            t = time.perf_counter()
            sum(1 for _ in iter_messages(path, views=True, verify_crc=False))
            t_views = time.perf_counter() - t
            size = sum(f.stat().st_size for f in path.iterdir()) / 1e6
            print(f"  {storage:7s} {str(compression):5s}: write {total_mb / t_write:7.1f} MB/s, "
                  f"read {total_mb / t_read:7.1f} MB/s ({n / t_read:7.0f} msg/s), as views "
                  f"{total_mb / t_views:7.1f} MB/s, on disk {size:5.1f} MB")


def bench_playback(tmp: Path, rate: float) -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import String

    from eye_in_hand.nodes.bag_player import BagPlayer

    n, period_ns = 200, 10_000_000
    path = tmp / f"play_{rate:g}"
    store = default_typestore()
    with BagWriter(path) as bag:
        bag.add_topic("/bench/chatter", "std_msgs/msg/String")
        for i in range(n):
            bag.write("/bench/chatter", T0 + i * period_ns,
                      serialize(store.types["std_msgs/msg/String"](data=str(i)),
                                "std_msgs/msg/String"))
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        arrivals: list[tuple[float, int]] = []
        sub = Node("bench_sub", context=context)
        sub.create_subscription(String, "/bench/chatter",
                                lambda m: arrivals.append((time.monotonic(), int(m.data))), 500)
        player = BagPlayer(context=context, parameter_overrides=[
            Parameter("bag", value=str(path)), Parameter("rate", value=rate),
            Parameter("wait_for_subscribers", value=10.0)])
        ex = SingleThreadedExecutor(context=context)
        ex.add_node(sub)
        ex.add_node(player)
        player.start()
        deadline = time.monotonic() + 60
        while (not player.finished or len(arrivals) < n) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        mono0, _ = player.playback.timebase  # type: ignore[misc]
        delays = np.array([(t - (mono0 + i * period_ns / 1e9 / rate)) * 1e3
                           for t, i in arrivals])
        print(f"playback at rate {rate:g} ({n} msgs at {1e9 / period_ns:.0f} Hz): "
              f"received {len(arrivals)}/{n}, delay after due time median "
              f"{np.median(delays):.2f} ms, p95 {np.percentile(delays, 95):.2f} ms, "
              f"max {delays.max():.2f} ms, min {delays.min():.2f} ms")
        ex.shutdown()
        player.destroy_node()
        sub.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def bench_record(tmp: Path, storage: str) -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Image

    from eye_in_hand.nodes.bag_recorder import BagRecorder

    n = 200
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        pub_node = Node("bench_pub", context=context)
        pub = pub_node.create_publisher(Image, "/bench/image", 100)
        rec = BagRecorder(context=context, parameter_overrides=[
            Parameter("output", value=str(tmp / f"rec_{storage}")),
            Parameter("topics", Parameter.Type.STRING_ARRAY, ["/bench/image"]),
            Parameter("storage", value=storage), Parameter("discovery_period", value=0.05)])
        ex = SingleThreadedExecutor(context=context)
        ex.add_node(pub_node)
        ex.add_node(rec)
        deadline = time.monotonic() + 20
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.02)
        rng = np.random.default_rng(1)
        img = Image(height=480, width=640, encoding="mono8", step=640,
                    data=rng.integers(0, 256, 640 * 480, dtype=np.uint8).tobytes())
        t = time.perf_counter()
        for _ in range(n):  # as fast as rclpy publishes, spinning the recorder in between
            pub.publish(img)
            ex.spin_once(timeout_sec=0)
        # until everything is accounted for, or nothing new for 2 s (DDS may lose samples
        # that a keep-last writer history overwrote before delivery)
        last_progress, seen, t_last = time.monotonic(), -1, t
        while time.monotonic() - last_progress < 2.0:
            done = rec.received.get("/bench/image", 0) + sum(rec.dropped.values())
            if done != seen:
                seen, last_progress, t_last = done, time.monotonic(), time.perf_counter()
            if done >= n:
                break
            ex.spin_once(timeout_sec=0.01)
        rec.close()
        elapsed = t_last - t
        got = rec.received.get("/bench/image", 0)
        print(f"record {storage:7s}: {n} images of 640x480 mono8 published back to back, "
              f"{got} written, {sum(rec.dropped.values())} dropped by the recorder, "
              f"{n - got - sum(rec.dropped.values())} lost in DDS; "
              f"{got * 307.2e-3 / elapsed:.1f} MB/s end to end ({elapsed:.2f} s)")
        ex.shutdown()
        rec.destroy_node()
        pub_node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def bench_zstd(bag: Path) -> None:
    """Decompression speed of a bag's zstd chunks, per CPU-second (load-independent-ish)."""
    import mmap

    from rosbags.rosbag2 import Reader

    from eye_in_hand.io.bags import mcap_chunks

    with Reader(bag) as reader:
        storage = reader.storage.storages[0]
        with open(storage.path, "rb") as fh:
            view = memoryview(mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ))
        chunks = [mcap_chunks._Chunk(c, view) for c in storage.chunks[:30]]
    chunks = [c for c in chunks if c.compression == "zstd"]
    if not chunks:
        print(f"zstd decompression: {bag} has no zstd chunks")
        return
    total = sum(c.size for c in chunks)
    try:
        from compression import zstd  # type: ignore[import-not-found]
    except ImportError:
        from backports import zstd  # type: ignore[no-redef]
    ways = {"without size (zstd.decompress)": lambda c: zstd.decompress(c.data),
            "with size (ZstdDecompressor, max_length)":
                lambda c: zstd.ZstdDecompressor().decompress(c.data, max_length=c.size)}
    used = mcap_chunks._decompressor("zstd")
    ways[f"mcap_chunks ({mcap_chunks.zstd_binding()})"] = lambda c: used(c.data, c.size)
    print(f"zstd decompression of {len(chunks)} chunks of {bag} ({total / 1e6:.0f} MB out, "
          f"compressed to {100 * sum(len(c.data) for c in chunks) / total:.0f} %):")
    for name, fn in ways.items():
        speeds = []
        for _ in range(5):
            t0 = time.process_time()
            for c in chunks:
                fn(c)
            speeds.append(total / max(time.process_time() - t0, 1e-9) / 1e9)
        speeds.sort()
        print(f"  {name:<45} best {speeds[-1]:.2f} GB/s, median {speeds[2]:.2f} GB/s "
              "per CPU-second")


def main() -> None:
    import sys

    root = Path(__file__).resolve().parent.parent
    for bag in (root / "bags" / "localization",
                root / "build" / "bench-data" / "loc600" / "localization"):
        if bag.exists():
            bench_zstd(bag)
    if "--zstd" in sys.argv[1:]:
        return
    with tempfile.TemporaryDirectory() as tmp:
        bench_io(Path(tmp))
        bench_playback(Path(tmp), 1.0)
        bench_playback(Path(tmp), 4.0)
        bench_record(Path(tmp), "mcap")
        bench_record(Path(tmp), "sqlite3")


if __name__ == "__main__":
    main()
