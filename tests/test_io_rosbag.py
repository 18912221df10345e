"""ROS 1 / ROS 2 bag readers: topic choice, message fields, the sequential ROS 1 fallback,
truncated bags and bad messages."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from _io_data import shared_log
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from bioslam.io.logs import TRUNCATED, WRONG_BEAM_COUNT, open_log
from bioslam.io.rosbag import LASERSCAN, parse_record_header

STORE1 = get_typestore(Stores.ROS1_NOETIC)
STORE2 = get_typestore(Stores.ROS2_HUMBLE)
N = 91


def scan_msg(store, t: float, n: int = N, ranges=None):
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    LaserScan = store.types[LASERSCAN]
    sec = int(t)
    stamp = Time(sec=sec, nanosec=round((t - sec) * 1e9))
    header = (Header(seq=0, stamp=stamp, frame_id="laser") if "seq" in Header.__dataclass_fields__
              else Header(stamp=stamp, frame_id="laser"))
    r = np.linspace(1.0, 2.0, n) + (t - 100.0) if ranges is None else ranges
    inc = np.pi / (N - 1)
    return LaserScan(
        header=header, angle_min=-np.pi / 2, angle_max=np.pi / 2,
        angle_increment=inc, time_increment=1e-4, scan_time=0.1, range_min=0.1,
        range_max=10.0, ranges=np.asarray(r, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def odom_msg(store):
    Pose = store.types["geometry_msgs/msg/Pose2D"]
    return Pose(x=1.0, y=2.0, theta=0.5)


def write_bag2(path, topics=("/scan",), count=5, storage=StoragePlugin.SQLITE3, extra=None):
    with Writer2(path, version=9, storage_plugin=storage) as writer:
        conns = {t: writer.add_connection(t, LASERSCAN, typestore=STORE2) for t in topics}
        other = writer.add_connection("/pose", "geometry_msgs/msg/Pose2D", typestore=STORE2)
        for k in range(count):
            t = 100.0 + 0.1 * k
            for name, conn in conns.items():
                msg = (extra or {}).get((name, k)) or scan_msg(STORE2, t)
                writer.write(conn, int(t * 1e9), STORE2.serialize_cdr(msg, LASERSCAN))
            writer.write(other, int(t * 1e9), STORE2.serialize_cdr(
                odom_msg(STORE2), "geometry_msgs/msg/Pose2D"))
    return path


def write_bag1(path, count=40, chunk_threshold=4000, compression=None):
    writer = Writer1(path)
    writer.chunk_threshold = chunk_threshold
    if compression:
        writer.set_compression(compression)
    with writer:
        conn = writer.add_connection("/scan", LASERSCAN, typestore=STORE1)
        for k in range(count):
            t = 100.0 + 0.1 * k
            writer.write(conn, int(t * 1e9), STORE1.serialize_ros1(scan_msg(STORE1, t), LASERSCAN))
    return path


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_rosbag2_directory_roundtrip(tmp_path, storage):
    bag = write_bag2(tmp_path / "bag", storage=storage)
    source = open_log(bag)
    assert source.format == "rosbag2" and source.topic == "/scan"
    scans = list(source)
    assert [round(s.stamp, 6) for s in scans] == [100.0, 100.1, 100.2, 100.3, 100.4]
    s = scans[2]
    assert s.ranges.dtype == np.float32
    np.testing.assert_allclose(s.ranges, np.linspace(1.0, 2.0, N) + 0.2, rtol=1e-6)
    np.testing.assert_allclose(s.angles[[0, -1]], [-np.pi / 2, np.pi / 2], atol=1e-6)
    assert (s.range_min, s.range_max) == pytest.approx((0.1, 10.0))
    assert s.time_increment == pytest.approx(1e-4)
    topics = {t["name"]: (t["type"], t["count"]) for t in source.topics()}
    assert topics == {"/scan": (LASERSCAN, 5), "/pose": ("geometry_msgs/msg/Pose2D", 5)}
    # the storage file alone is a bag too
    (storage_file,) = [p for p in bag.iterdir() if p.suffix in (".db3", ".mcap")]
    assert sum(1 for _ in open_log(storage_file)) == 5


def test_several_scan_topics_need_a_choice(tmp_path):
    bag = write_bag2(tmp_path / "bag", topics=("/front/scan", "/rear/scan"))
    with pytest.raises(ValueError, match=r"several LaserScan topics.*/front/scan, /rear/scan"):
        open_log(bag)
    assert open_log(bag, topic="rear/scan").topic == "/rear/scan"
    with pytest.raises(ValueError, match=r"'/pose' is not a sensor_msgs/LaserScan topic"):
        open_log(bag, topic="/pose")


def test_bad_messages_are_skipped(tmp_path):
    extra = {
        ("/scan", 1): scan_msg(STORE2, 100.1, n=N - 10),  # angles describe N beams
        ("/scan", 2): scan_msg(STORE2, 100.2, ranges=np.full(N, np.nan, np.float32)),
        ("/scan", 3): scan_msg(STORE2, 100.3, ranges=np.zeros(0, np.float32)),
    }
    bag = write_bag2(tmp_path / "bag", extra=extra)
    source = open_log(bag)
    assert [round(s.stamp, 6) for s in source] == [100.0, 100.4]
    skipped = source.skipped
    assert skipped[WRONG_BEAM_COUNT] == 1
    assert len(skipped) == 3  # wrong count, no valid returns, empty
    assert "message 2 on /scan" in source.skip_examples[WRONG_BEAM_COUNT]


@pytest.mark.parametrize("compression", [None, Writer1.CompressionFormat.BZ2,
                                         Writer1.CompressionFormat.LZ4])
def test_rosbag1_indexed_and_sequential_agree(tmp_path, compression):
    bag = write_bag1(tmp_path / "a.bag", compression=compression)
    source = open_log(bag)
    assert source.format == "rosbag1"
    indexed = [(s.stamp, s.ranges.copy()) for s in source]
    assert len(indexed) == 40 and source.notes() == []
    # Break the index as laser_scan_matcher_demo.bag does: a wrong index-data length.
    broken = tmp_path / "broken.bag"
    broken.write_bytes(_with_bad_index_lengths(bag.read_bytes()))
    fallback = open_log(broken)
    sequential = [(s.stamp, s.ranges) for s in fallback]
    assert any("sequentially" in note for note in fallback.notes())
    assert len(sequential) == 40 and fallback.skipped == {}
    for (ta, ra), (tb, rb) in zip(indexed, sequential, strict=True):
        assert ta == tb
        np.testing.assert_array_equal(ra, rb)


def _with_bad_index_lengths(data: bytes) -> bytes:
    """The bag with every top-level index-data record declaring 20 bytes per entry."""
    out = bytearray(data)
    pos = data.index(b"\n") + 1
    patched = 0
    while pos < len(data):
        (header_len,) = struct.unpack_from("<I", data, pos)
        header = parse_record_header(data[pos + 4 : pos + 4 + header_len])
        size_at = pos + 4 + header_len
        (data_len,) = struct.unpack_from("<I", data, size_at)
        if header["op"] == b"\x04":
            (count,) = struct.unpack("<I", header["count"])
            struct.pack_into("<I", out, size_at, count * 20)
            patched += 1
        pos = size_at + 4 + data_len
    assert patched > 1
    return bytes(out)


def test_truncated_rosbag1_keeps_what_was_read(tmp_path):
    bag = write_bag1(tmp_path / "a.bag", count=60)
    data = bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    source = open_log(cut)
    scans = list(source)
    assert 20 <= len(scans) < 60
    assert source.skipped == {TRUNCATED: 1}
    assert np.all(np.diff([s.stamp for s in scans]) > 0)
    with pytest.raises(ValueError, match=r"cut\.bag: .*truncated"):
        list(open_log(cut, strict=True))


def test_garbage_bag_is_a_clear_error(tmp_path):
    bag = tmp_path / "junk.bag"
    bag.write_bytes(b"not a bag at all\n" * 10)
    with pytest.raises(ValueError, match=r"junk\.bag: unknown log format.*suggests rosbag1"):
        open_log(bag)
    with pytest.raises(ValueError, match=r"junk\.bag: not a ROS 1 v2\.0 bag"):
        open_log(bag, fmt="rosbag1")
    db = tmp_path / "junk.db3"
    db.write_bytes(b"SQLite format 3\x00" + b"\x00" * 100)
    with pytest.raises(ValueError, match=r"junk\.db3: cannot open the database"):
        open_log(db)


def test_real_demo_bag_falls_back_and_yields_every_scan():
    source = open_log(shared_log("laser_scan_matcher_demo.bag"))
    scans = list(source)
    assert len(scans) == 360
    assert {s.num_beams for s in scans} == {681}
    assert scans[-1].stamp - scans[0].stamp == pytest.approx(35.8, abs=0.1)
    assert scans[0].time_increment > 0
    assert source.skipped == {}
    assert any("sequentially" in note for note in source.notes())


def test_truncated_mcap_keeps_what_was_read(tmp_path):
    bag = write_bag2(tmp_path / "bag", count=60, storage=StoragePlugin.MCAP)
    (mcap,) = bag.glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[: int(len(data) * 0.6)])
    source = open_log(bag)
    scans = list(source)
    assert 20 <= len(scans) < 60
    assert source.skipped == {TRUNCATED: 1}
    assert any("record by record" in note for note in source.notes())
    np.testing.assert_allclose(scans[5].ranges, np.linspace(1.0, 2.0, N) + 0.5, rtol=1e-6)


def test_damaged_db3_is_a_clear_error(tmp_path):
    bag = write_bag2(tmp_path / "bag", count=60)
    (db3,) = bag.glob("*.db3")
    data = db3.read_bytes()
    db3.write_bytes(data[: len(data) // 3])
    with pytest.raises(ValueError, match=r"bag\.db3"):
        list(open_log(bag))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_reads_the_simulator_bag_writer_output(tmp_path, storage):
    from bioslam.io.bag_writer import write_scan_bag
    from bioslam.scan import LaserScan

    angles = np.linspace(-2.0, 2.0, 50)
    written = [
        LaserScan(10.0 + 0.025 * k, np.full(50, 1.0 + k, dtype=np.float32), angles, 0.1, 30.0,
                  1e-5)
        for k in range(8)
    ]
    write_scan_bag(tmp_path / "scans", written, scan_time=0.025, storage=storage,
                   pose_topic="/ground_truth")
    source = open_log(tmp_path / "scans")
    assert source.topic == "/scan"
    read = list(source)
    assert len(read) == 8
    for a, b in zip(written, read, strict=True):
        assert b.stamp == pytest.approx(a.stamp, abs=1e-9)
        np.testing.assert_allclose(b.angles, a.angles, atol=1e-6)
        np.testing.assert_array_equal(b.ranges, a.ranges)
        assert b.time_increment == pytest.approx(1e-5)
