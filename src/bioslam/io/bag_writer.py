"""Write LaserScans to a ROS 2 bag (``sensor_msgs/msg/LaserScan``), via ``rosbags``.

The bag is what ``ros2 bag play`` replays and what :func:`bioslam.io.logs.open_log` reads:
each scan's header stamp is its first-beam time, ``time_increment`` and ``scan_time`` say how
the beams were swept, and ranges use the REP 117 codes the scan carries (``inf`` no return,
``-inf`` too close, NaN dropout). Ground-truth poses can go beside the scans as
``geometry_msgs/msg/PoseStamped`` on their own topic.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from types import TracebackType

import numpy as np
from numpy.typing import ArrayLike
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from bioslam.scan import LaserScan

SCAN_MSGTYPE = "sensor_msgs/msg/LaserScan"
POSE_MSGTYPE = "geometry_msgs/msg/PoseStamped"
STORAGES = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
# Bag format version 8 (ROS 2 Iron/Jazzy); the oldest rosbags writes, so the widest readable.
_BAG_VERSION = 8
# Beam angles may deviate this much (radians) from a uniform layout before the scan is refused:
# a LaserScan message can only describe evenly spaced beams.
_ANGLE_TOLERANCE = 1e-6


def _nanoseconds(stamp: float) -> int:
    return round(stamp * 1e9)


class ScanBagWriter:
    """A ROS 2 bag being written; use as a context manager.

    ``path`` must not exist yet (rosbag2 refuses to overwrite). ``storage`` is ``"sqlite3"``
    (``.db3``, the ROS 2 default up to Humble) or ``"mcap"``. ``scan_time`` is written into every
    message (seconds between scans).
    """

    def __init__(
        self,
        path: str | Path,
        topic: str = "/scan",
        frame_id: str = "laser",
        scan_time: float = 0.0,
        storage: str = "sqlite3",
        pose_topic: str | None = None,
        map_frame: str = "map",
    ) -> None:
        if storage not in STORAGES:
            raise ValueError(f"unknown bag storage {storage!r}; choose one of {list(STORAGES)}")
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f"{self.path}: already exists; a bag is never overwritten")
        self.topic, self.frame_id, self.scan_time = topic, frame_id, float(scan_time)
        self.pose_topic, self.map_frame = pose_topic, map_frame
        self.count = 0
        self._typestore = get_typestore(Stores.ROS2_HUMBLE)
        self._writer = Writer(self.path, version=_BAG_VERSION, storage_plugin=STORAGES[storage])
        self._scan_conn = None
        self._pose_conn = None
        self._last_angles: np.ndarray | None = None
        self._last_layout = (0.0, 0.0, 0.0)

    def __enter__(self) -> ScanBagWriter:
        self._writer.open()
        self._scan_conn = self._writer.add_connection(
            self.topic, SCAN_MSGTYPE, typestore=self._typestore
        )
        if self.pose_topic:
            self._pose_conn = self._writer.add_connection(
                self.pose_topic, POSE_MSGTYPE, typestore=self._typestore
            )
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._writer.close()

    def _header(self, stamp: float, frame_id: str) -> object:
        types = self._typestore.types
        ns = _nanoseconds(stamp)
        time = types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        return types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def _angle_layout(self, scan: LaserScan) -> tuple[float, float, float]:
        """``(angle_min, angle_max, angle_increment)``, checked once per distinct angle array
        (a simulator or driver reuses one array for every scan)."""
        if scan.angles is self._last_angles:
            return self._last_layout
        n = scan.num_beams
        angle_min = float(scan.angles[0]) if n else 0.0
        angle_max = float(scan.angles[-1]) if n else 0.0
        increment = (angle_max - angle_min) / (n - 1) if n > 1 else 0.0
        uniform = angle_min + increment * np.arange(n)
        if n and np.max(np.abs(uniform - scan.angles)) > _ANGLE_TOLERANCE:
            raise ValueError(
                f"scan at {scan.stamp:.6f} s: beam angles are not evenly spaced, which a "
                "sensor_msgs/LaserScan cannot describe"
            )
        self._last_angles, self._last_layout = scan.angles, (angle_min, angle_max, increment)
        return self._last_layout

    def write(self, scan: LaserScan) -> None:
        """Append one scan (stamps must be >= 0 and should increase)."""
        if self._scan_conn is None:
            raise RuntimeError("ScanBagWriter.write called outside its 'with' block")
        if not scan.stamp >= 0.0:
            raise ValueError(f"scan stamp must be >= 0 for a ROS time, got {scan.stamp}")
        angle_min, angle_max, increment = self._angle_layout(scan)
        msg = self._typestore.types[SCAN_MSGTYPE](
            header=self._header(scan.stamp, self.frame_id),
            angle_min=angle_min,
            angle_max=angle_max,
            angle_increment=increment,
            time_increment=float(scan.time_increment),
            scan_time=self.scan_time,
            range_min=float(scan.range_min),
            range_max=float(scan.range_max),
            ranges=np.asarray(scan.ranges, dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        data = self._typestore.serialize_cdr(msg, SCAN_MSGTYPE)
        self._writer.write(self._scan_conn, _nanoseconds(scan.stamp), data)
        self.count += 1

    def write_pose(self, stamp: float, pose: ArrayLike) -> None:
        """Append a pose ``(x, y, theta)`` in the map frame (needs ``pose_topic``)."""
        if self._pose_conn is None:
            raise RuntimeError("ScanBagWriter has no pose topic (pass pose_topic=...)")
        x, y, theta = (float(v) for v in np.asarray(pose, dtype=np.float64).reshape(3))
        types = self._typestore.types
        qz, qw = math.sin(0.5 * theta), math.cos(0.5 * theta)
        msg = types[POSE_MSGTYPE](
            header=self._header(stamp, self.map_frame),
            pose=types["geometry_msgs/msg/Pose"](
                position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=qz, w=qw),
            ),
        )
        data = self._typestore.serialize_cdr(msg, POSE_MSGTYPE)
        self._writer.write(self._pose_conn, _nanoseconds(stamp), data)


def write_scan_bag(
    path: str | Path, scans: Iterable[LaserScan], scan_time: float = 0.0, **kwargs: object
) -> int:
    """Write all ``scans`` to a new ROS 2 bag at ``path``; returns how many were written.
    ``kwargs`` go to :class:`ScanBagWriter`."""
    with ScanBagWriter(path, scan_time=scan_time, **kwargs) as writer:  # type: ignore[arg-type]
        for scan in scans:
            writer.write(scan)
        return writer.count
