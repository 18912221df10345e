"""CARMEN logs (``.log``/``.clf``, plain or gzipped): ``FLASER``, ``RLASER``, ``ROBOTLASER1/2``,
``RAWLASER1..4`` scans and ``ODOM`` wheel odometry.

Line layouts (CARMEN logger, ``carmen/src/logger/writelog.c``)::

    FLASER n r_1..r_n x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp
    ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r_1..r_n
        m rem_1..rem_m laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
        forward_safety_dist side_safety_dist turn_axis ipc_timestamp ipc_hostname logger_timestamp
    RAWLASER1 type start_angle fov resolution max_range accuracy remission_mode n r_1..r_n
        m rem_1..rem_m ipc_timestamp ipc_hostname logger_timestamp
    ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp

Scans are stamped with ``ipc_timestamp``. CARMEN does not say whether the poses in a log are raw
odometry or corrected: the laser pose of ``FLASER``/``ROBOTLASER1`` lines is exposed as
``reference`` when :attr:`CarmenConfig.corrected` says so (by default: when the file name contains
"corrected", the naming of the Radish data sets' corrected logs).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bioslam.io.logs import (
    MALFORMED,
    ODOMETRY_MALFORMED,
    WRONG_BEAM_COUNT,
    BadRecordError,
    LogSource,
    Pose,
)
from bioslam.scan import LaserScan

# Preference when a log holds several laser messages and no topic is given: messages carrying
# their own angles first, the front laser before the rear one.
LASER_MESSAGES = (
    "ROBOTLASER1", "FLASER", "RAWLASER1", "ROBOTLASER2", "RLASER", "RAWLASER2", "RAWLASER3",
    "RAWLASER4",
)
# Fields after the remissions in ROBOTLASER lines (up to and including logger_timestamp).
_ROBOTLASER_TAIL = 14
# Fields after the remissions in RAWLASER lines: ipc_timestamp ipc_hostname logger_timestamp.
_RAWLASER_TAIL = 3


def _ranges(fields: list[str]) -> NDArray[np.float32]:
    """A line's ranges as float32. A value beyond float32 (a corrupt digit run) becomes
    infinite, which the scan's validity mask rejects and counts like any other bad range, so
    the overflow is expected here and not worth a warning on the user's terminal."""
    with np.errstate(over="ignore"):
        return np.array(fields, dtype=np.float32)


@dataclass(frozen=True)
class CarmenConfig:
    """Options of the CARMEN reader.

    Attributes:
        flaser_fov_deg: field of view of ``FLASER``/``RLASER`` lines, which carry no angles;
            180° is CARMEN's convention for them (SICK LMS 2xx front/rear lasers).
        flaser_max_range_m: range limit of ``FLASER``/``RLASER`` lines, which carry none; 80 m is
            the SICK LMS 2xx maximum in cm mode, whose "no return" codes (81.83, 81.91 m) lie
            just above it.
        corrected: whether the laser poses in the log are corrected (a reference trajectory);
            ``None`` = decide from the file name ("corrected" in it), as the Radish logs are named.
        head_lines: lines read at opening to find which laser messages the log has.
    """

    flaser_fov_deg: float = 180.0
    flaser_max_range_m: float = 80.0
    corrected: bool | None = None
    head_lines: int = 5000


def _last_float(line: str) -> float:
    """The last field of a line (the logger_timestamp of every timed message), NaN if none."""
    try:
        return float(line.rsplit(None, 1)[-1])
    except (ValueError, IndexError):
        return float("nan")


class CarmenLog(LogSource):
    """A CARMEN log; ``topic`` is the laser message name (e.g. ``FLASER``, ``ROBOTLASER1``)."""

    format = "carmen"
    alternative_stamps = "logger_timestamp"

    def __init__(
        self,
        path: str | Path,
        topic: str | None = None,
        strict: bool = False,
        config: CarmenConfig | None = None,
    ) -> None:
        super().__init__(path, topic, strict)
        self.config = config or CarmenConfig()
        self._corrected = (
            self.config.corrected
            if self.config.corrected is not None
            else "corrected" in self.path.name.lower()
        )
        self._message_counts: Counter[str] = self._count_head()
        self.topic = self._choose_topic(topic)
        self._flaser_angles: dict[int, NDArray[np.float64]] = {}

    def _count_head(self) -> Counter[str]:
        counts: Counter[str] = Counter()
        with closing(self._lines()) as lines:
            for lineno, line in lines:
                word = line.split(maxsplit=1)[0] if line.strip() else ""
                if word in LASER_MESSAGES:
                    counts[word] += 1
                if lineno >= self.config.head_lines:
                    break
        self._skipped.clear()  # a truncation seen here is counted again by the real pass
        self.skip_examples.clear()
        return counts

    def _choose_topic(self, topic: str | None) -> str:
        if topic is not None:
            if topic not in LASER_MESSAGES:
                raise ValueError(
                    f"{self.path}: unknown CARMEN laser message {topic!r}; "
                    f"expected one of {', '.join(LASER_MESSAGES)}"
                )
            return topic
        for name in LASER_MESSAGES:
            if self._message_counts[name]:
                return name
        # Nothing in the head: FLASER, the commonest; an empty result is reported by info().
        return "FLASER"

    def topics(self) -> list[dict[str, Any]]:
        return [
            {"name": name, "type": "carmen/" + name, "count": count}
            for name, count in sorted(self._message_counts.items())
        ]

    def _format_notes(self) -> list[str]:
        kind = "corrected (used as reference)" if self._corrected else "raw (no reference)"
        return [f"laser poses taken as {kind}; message {self.topic} read"]

    # -- parsing -------------------------------------------------------------------------------
    def _records(self) -> Iterator[tuple[LaserScan, str, Pose | None]]:
        counts: Counter[str] = Counter()
        parse = {
            "FLASER": self._parse_flaser,
            "RLASER": self._parse_flaser,
            "ROBOTLASER1": self._parse_robotlaser,
            "ROBOTLASER2": self._parse_robotlaser,
        }.get(self.topic, self._parse_rawlaser)
        for lineno, line in self._lines():
            head = line.split(None, 1)
            if not head:
                continue
            word = head[0]
            if word in LASER_MESSAGES:
                counts[word] += 1
            if word != self.topic and word != "ODOM":
                continue
            where = f"line {lineno}"
            try:
                if word == "ODOM":
                    # only the first 8 fields matter: skip splitting the rest
                    self._parse_odom(line.split(None, 8), where)
                    continue
                record = parse(line.split(), where)
            except BadRecordError:
                raise  # strict: the parser's own report, not a malformed line
            except (ValueError, IndexError, OverflowError) as exc:
                # a bad ODOM line is side data: it must not count as a scan record
                reason = ODOMETRY_MALFORMED if word == "ODOM" else MALFORMED
                self._skip(reason, where, f"{word}: {exc}")
                continue
            if record is not None:
                self._alternative_stamp(_last_float(line))
                yield record
        self._message_counts = counts

    def _parse_odom(self, fields: list[str], where: str) -> None:
        if len(fields) < 8:
            self._skip(ODOMETRY_MALFORMED, where,
                       f"ODOM needs at least 8 fields, got {len(fields)}")
            return
        x, y, theta = (float(v) for v in fields[1:4])
        self._add_odometry(float(fields[7]), (x, y, theta), where)

    def _beam_count(self, fields: list[str], index: int, where: str) -> int | None:
        n = int(fields[index])
        if n < 0:
            self._skip(WRONG_BEAM_COUNT, where, f"{fields[0]} declares {n} beams")
            return None
        return n

    def _flaser_angles_for(self, n: int) -> NDArray[np.float64]:
        angles = self._flaser_angles.get(n)
        if angles is None:
            # 180/181 beams are 1° apart and 360/361 beams 0.5°: an odd count includes both
            # ends of the field of view, an even one does not.
            fov = np.radians(self.config.flaser_fov_deg)
            step = fov / (n - 1) if n % 2 and n > 1 else fov / max(n, 1)
            angles = (np.arange(n) - (n - 1) / 2.0) * step
            self._flaser_angles[n] = angles
        return angles

    def _parse_flaser(
        self, fields: list[str], where: str
    ) -> tuple[LaserScan, str, Pose | None] | None:
        n = self._beam_count(fields, 1, where)
        if n is None:
            return None
        # pose, odometry pose, ipc_timestamp, ipc_hostname and logger_timestamp follow the ranges
        if len(fields) != n + 11:
            self._skip(
                WRONG_BEAM_COUNT, where,
                f"{fields[0]} declares {n} beams but the line has {len(fields)} fields "
                f"(expected {n + 11})",
            )
            return None
        ranges = _ranges(fields[2 : 2 + n])
        tail = [float(v) for v in fields[2 + n : 2 + n + 7]]
        scan = LaserScan(
            tail[6], ranges, self._flaser_angles_for(n), 0.0, self.config.flaser_max_range_m
        )
        return scan, where, self._reference_pose(tail[0:3])

    def _laser_header(
        self, fields: list[str], where: str, tail: int
    ) -> tuple[NDArray[np.float32], NDArray[np.float64], float, int] | None:
        """Ranges, angles, max range and the index after the remissions of a ROBOTLASER or
        RAWLASER line (``tail`` fields follow them), or None (counted) when the declared
        counts do not fit the line."""
        n = self._beam_count(fields, 8, where)
        if n is None:
            return None
        try:
            m = int(fields[9 + n])
        except (IndexError, ValueError):
            m = -1
        end = 10 + n + m
        if m < 0 or len(fields) != end + tail:
            self._skip(
                WRONG_BEAM_COUNT, where,
                f"{fields[0]} declares {n} beams but the line has {len(fields)} fields",
            )
            return None
        start, _fov, resolution, max_range = (float(v) for v in fields[2:6])
        ranges = _ranges(fields[9 : 9 + n])
        # CARMEN writes max_range for "no return": make such beams invalid.
        ranges[ranges >= max_range] = np.inf
        angles = start + resolution * np.arange(n, dtype=np.float64)
        return ranges, angles, max_range, end

    def _parse_robotlaser(
        self, fields: list[str], where: str
    ) -> tuple[LaserScan, str, Pose | None] | None:
        parsed = self._laser_header(fields, where, _ROBOTLASER_TAIL)
        if parsed is None:
            return None
        ranges, angles, max_range, end = parsed
        laser_pose = [float(v) for v in fields[end : end + 3]]
        scan = LaserScan(float(fields[end + 11]), ranges, angles, 0.0, max_range)
        return scan, where, self._reference_pose(laser_pose)

    def _parse_rawlaser(
        self, fields: list[str], where: str
    ) -> tuple[LaserScan, str, Pose | None] | None:
        parsed = self._laser_header(fields, where, _RAWLASER_TAIL)
        if parsed is None:
            return None
        ranges, angles, max_range, end = parsed
        return LaserScan(float(fields[end]), ranges, angles, 0.0, max_range), where, None

    def _reference_pose(self, pose: list[float]) -> Pose | None:
        return (pose[0], pose[1], pose[2]) if self._corrected else None
