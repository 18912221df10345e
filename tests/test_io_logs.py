"""Format detection, the common source API and the time-order rules shared by all readers."""

from __future__ import annotations

import gzip
from collections.abc import Iterator

import numpy as np
import pytest

from bioslam.io.logs import (
    NON_MONOTONIC,
    SUPPORTED_FORMATS,
    LogSource,
    Pose,
    StampedPoses,
    detect_format,
    open_log,
)
from bioslam.scan import LaserScan

FLASER = "FLASER 3 1 1 1 0 0 0 0 0 0 {t} host {t}\n"


def test_detect_by_content_whatever_the_name(tmp_path):
    carmen = "PARAM x 1 0 h 0\n" + FLASER.format(t=1.0)
    breezy = " ".join(["1000"] * 707) + "\n"
    bag1 = b"#ROSBAG V2.0\n" + b"\x00" * 64
    for name, content, fmt in [
        ("a.dat", carmen, "carmen"),  # a CARMEN log named .dat
        ("a.log", breezy, "breezyslam"),
        ("a.log", bag1, "rosbag1"),  # a ROS 1 bag named .log
        ("a.bag", b"SQLite format 3\x00" + b"\x00" * 64, "rosbag2"),
        ("a.db3", b"\x89MCAP0\r\n" + b"\x00" * 64, "rosbag2"),
    ]:
        path = tmp_path / f"{fmt}-{name}"
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        assert detect_format(path) == fmt, name
    bag_dir = tmp_path / "bagdir"
    bag_dir.mkdir()
    (bag_dir / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    assert detect_format(bag_dir) == "rosbag2"


def test_a_misnamed_log_is_read_and_the_name_noted(tmp_path):
    path = tmp_path / "scans.dat"
    path.write_text("".join(FLASER.format(t=1.0 + k) for k in range(3)))
    source = open_log(path)
    assert source.format == "carmen" and sum(1 for _ in source) == 3
    assert any("named like a breezyslam log" in note for note in source.notes())


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("random.log", bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8)),
         "its name suggests carmen"),
        ("empty.log", b"", "empty"),
        ("blank.dat", b"\n\n  \n", "empty"),
        ("prose.bag", b"hello world\nthis is not a bag\n", "its name suggests rosbag1"),
        ("notes.txt", b"hello world\n", "unknown log format"),
    ],
)
def test_unreadable_content_is_a_clear_error_naming_the_file(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message) as info:
        open_log(path)
    assert str(path) in str(info.value)


def test_detect_by_content_when_extension_says_nothing(tmp_path):
    carmen = tmp_path / "robot.txt"
    carmen.write_text("# log\nPARAM x 1 0 h 0\n" + FLASER.format(t=1.0) * 3)
    assert detect_format(carmen) == "carmen"
    zipped = tmp_path / "robot.gz"
    with gzip.open(zipped, "wt") as fh:
        fh.write(FLASER.format(t=1.0) * 3)
    assert detect_format(zipped) == "carmen"
    source = open_log(zipped)
    assert sum(1 for _ in source) == 3  # one stamp for all three: read in record order
    assert source.time_source.startswith("record order")
    breezy = tmp_path / "rover.log2"
    breezy.write_text(" ".join(["1000"] * 707) + "\n")
    assert detect_format(breezy) == "breezyslam"
    bag = tmp_path / "capture"
    bag.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 64)
    assert detect_format(bag) == "rosbag1"
    mcap = tmp_path / "capture2"
    mcap.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 64)
    assert detect_format(mcap) == "rosbag2"


def test_unknown_format_lists_the_supported_ones(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("hello world\n")
    with pytest.raises(ValueError, match="unknown log format") as info:
        open_log(path)
    for name in SUPPORTED_FORMATS:
        assert name in str(info.value)
    with pytest.raises(FileNotFoundError, match=r"missing\.log"):
        open_log(tmp_path / "missing.log")


class _Scripted(LogSource):
    """A source replaying given stamps, to test the ordering rules on their own."""

    format = "carmen"

    def __init__(self, path, stamps, window=2.0):
        super().__init__(path)
        self.stamps = stamps
        self.reorder_window_s = window

    def _records(self) -> Iterator[tuple[LaserScan, str, Pose | None]]:
        for k, t in enumerate(self.stamps):
            scan = LaserScan(t, np.ones(4), np.linspace(-1, 1, 4))
            yield scan, f"record {k + 1}", (float(k), 0.0, 0.0)


@pytest.mark.parametrize(
    ("stamps", "expected", "order"),
    [
        ([1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [0, 1, 2]),
        ([1.0, 3.0, 2.5, 4.0], [1.0, 2.5, 3.0, 4.0], [0, 2, 1, 3]),  # 0.5 s late: reordered
        # 7 s ahead of its neighbours: repaired between them, the rest kept
        ([1.0, 2.0, 10.0, 3.0, 11.0], [1.0, 2.0, 2.5, 3.0, 11.0], [0, 1, 2, 3, 4]),
        ([1.0, 2.0, 2.0, 3.0], [1.0, 1.5, 2.0, 3.0], [0, 1, 2, 3]),  # repeated stamp
        ([1.0, np.nan, 2.0], [1.0, 1.5, 2.0], [0, 1, 2]),
        ([5.0, 6.0, 0.0, 7.0], [5.0, 6.0, 6.5, 7.0], [0, 1, 2, 3]),  # a clock glitch
    ],
)
def test_time_order_rules(tmp_path, stamps, expected, order):
    source = _Scripted(tmp_path, stamps)
    assert [s.stamp for s in source] == expected
    assert source.skipped.get(NON_MONOTONIC, 0) == 0
    assert source.records_seen == source.scans_read == len(stamps)
    # reference poses follow their scans through the reordering
    ref = source.reference
    np.testing.assert_array_equal(ref.stamps, expected)
    np.testing.assert_array_equal(ref.poses[:, 0], order)


def test_side_data_reads_the_log_when_not_iterated_yet(tmp_path):
    source = _Scripted(tmp_path, [1.0, 2.0])
    assert len(source.reference) == 2 and source.skipped == {}
    info = source.info()
    assert (info["scans"], info["beams"]) == (2, 4)
    assert info["fov_deg"] == pytest.approx(np.degrees(2.0))
    assert info["duration_s"] == pytest.approx(1.0)


def test_side_data_after_a_partial_iteration_cover_the_scans_read(tmp_path):
    source = _Scripted(tmp_path, [1.0, 2.0, 3.0, 4.0, 5.0], window=0.0)
    for scan in source:
        if scan.stamp >= 2.0:
            break
    assert not source.complete
    np.testing.assert_array_equal(source.reference.stamps, [1.0, 2.0])
    assert list(source) and source.complete and len(source.reference) == 5


def test_stamped_poses_keep_each_pose_exactly_in_32_bytes():
    """A log's reference poses, one per scan over an hour at 40 Hz: kept as rows of four
    float64 (stamp, x, y, theta), read back exactly and in order."""
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(10_000, 4))
    rows[:, 0] = np.cumsum(rng.uniform(0.01, 0.05, size=rows.shape[0]))
    poses = StampedPoses()
    assert poses.trajectory() is None
    for stamp, x, y, theta in rows:
        poses.append(float(stamp), (float(x), float(y), float(theta)))
    assert len(poses) == rows.shape[0]
    assert poses.last_pose() == tuple(rows[-1, 1:])
    assert poses.last_stamp() == rows[-1, 0]
    trajectory = poses.trajectory()
    np.testing.assert_array_equal(trajectory.stamps, rows[:, 0])
    np.testing.assert_array_equal(trajectory.poses, rows[:, 1:])
    assert poses._rows.nbytes <= 2 * 32 * rows.shape[0]  # the rows and at most doubling slack
