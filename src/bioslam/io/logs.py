"""Opening a LiDAR log: format detection and the source API every reader implements.

``open_log(path)`` returns a :class:`LogSource`; iterating it yields :class:`LaserScan` records in
strictly increasing time order, streamed from the file. Records that cannot be used are skipped
and counted by reason in ``source.skipped`` (the first occurrence of each reason is kept, with
its line or record number, in ``source.skip_examples``); with ``strict=True`` the first such
record raises a ``ValueError`` naming the file, the record and the problem instead.

Before the first scan is yielded the stamps of all scan records are checked as a whole
(:mod:`bioslam.io.timestamps`): isolated bad stamps are repaired from their neighbours, and a
log whose stamps are unusable is read in record order at the rate the log declares or its
stamps imply. ``source.time_source`` and ``source.notes()`` say which.
"""

from __future__ import annotations

import bz2
import dataclasses
import gzip
import heapq
import lzma
import re
import zlib
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import IO, Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from bioslam.growing import GrowingArray
from bioslam.io.timestamps import RECORD_ORDER, TimePlan, plan_stamps
from bioslam.memory import release_free_memory
from bioslam.scan import LaserScan
from bioslam.trajectory import Trajectory

Pose = tuple[float, float, float]

SUPPORTED_FORMATS: dict[str, str] = {
    "carmen": "CARMEN log: .log, .clf, optionally gzipped (.gz); FLASER, ROBOTLASER1, "
    "RAWLASER1-4, ODOM",
    "rosbag1": "ROS 1 bag (.bag) with sensor_msgs/LaserScan",
    "rosbag2": "ROS 2 bag: directory with metadata.yaml, .db3 or .mcap, sensor_msgs/LaserScan",
    "breezyslam": "BreezySLAM log (.dat): one line per scan, timestamp in µs, ranges in mm",
}

# Skip reasons shared by all readers (keys of ``LogSource.skipped``).
MALFORMED = "malformed record"
WRONG_BEAM_COUNT = "wrong beam count"
NON_MONOTONIC = "non-monotonic timestamp (not later than the previous scan)"
EMPTY_SCAN = "empty scan (no beams)"
NO_VALID_RETURNS = "no valid returns (all beams NaN, inf, zero or out of range)"
ODOMETRY_NON_MONOTONIC = "odometry record with non-monotonic timestamp"
ODOMETRY_MALFORMED = "malformed odometry record"
TRUNCATED = "truncated or corrupt part of the file (reading stopped there, or resumed after it)"
DAMAGED = "scan record lost in a damaged part of the file"

#: Range bytes of a log kept from the planning pass for the first iteration (above: parsed twice).
#: Small, because what is kept stays resident until the run has read it: the 600 s simulated
#: route (24,000 scans of 1081 beams) would keep 106 MB; reading it twice costs about 1 s.
REPLAY_BUDGET_BYTES = 32 * 2**20
_SCAN, _SKIP, _ODOMETRY = 0, 1, 2


class BadRecordError(ValueError):
    """A strict read's first unusable record (the message names the file and the record).
    A reader's own parsing errors must let it through unchanged."""


@dataclasses.dataclass(frozen=True)
class ReadState:
    """A source's read-outs as they stood at one moment of an iteration: what a copy of the
    source read elsewhere (:class:`bioslam.io.readahead.ReadAhead`) reports in its place."""

    scans_read: int
    records_seen: int
    complete: bool
    skipped: dict[str, int]
    skip_examples: dict[str, str]
    notes: list[str]
    time_plan: TimePlan | None


class LogSource(ABC):
    """A LiDAR log opened for reading. Subclasses implement :meth:`_records`.

    Attributes:
        path: the file or bag directory.
        format: one of :data:`SUPPORTED_FORMATS`.
        topic: the scan stream read (ROS topic, CARMEN message name), ``None`` when the format
            has a single stream.
        strict: raise on the first bad record instead of skipping it.
    """

    format: ClassVar[str] = ""
    #: The second stamp a record carries, if any (CARMEN's logger_timestamp, a bag's record
    #: time): used when the main stamps are unusable.
    alternative_stamps: ClassVar[str] = ""
    #: Seconds a record may arrive late and still be put back in order (see ``_Reorder``).
    #: 0 by default, none is: a scanner delivers its scans in order and a logger writes them
    #: as they come, so a scan stamped before the one written ahead of it carries a wrong
    #: stamp, repaired in its place (:func:`bioslam.io.timestamps.plan_stamps`). Intel's four such
    #: scans (0.1-0.86 s early) are in file order by its corrected poses (turns of 30° a scan,
    #: in sequence); put back in stamp order, the odometry turned 62° and back, and with
    #: freiburg-079's stamps jittered by 0.2 s the swapped scans broke the odometry's chain
    #: 147 times and left 7 of its 120 loop closures (``benchmarks/README.md``).
    reorder_window_s: float = 0.0

    def __init__(self, path: str | Path, topic: str | None = None, strict: bool = False) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such file or directory")
        self.topic = topic
        self.strict = strict
        self._skipped: Counter[str] = Counter()
        self.skip_examples: dict[str, str] = {}
        self._reference = StampedPoses()
        self._odometry = StampedPoses()
        #: Remarks made when the log was opened (e.g. its name suggests another format).
        self.open_notes: list[str] = []
        self._complete = False
        self._iterating = False
        self._order: _Reorder | None = None
        self._yielded = 0
        #: Scan period the log declares (e.g. a ROS ``scan_time``); readers set it while reading.
        self._declared_period: float | None = None
        self._plan: TimePlan | None = None
        self._produced = 0  # scan records produced by ``_records`` in the current pass
        self._odometry_slots: list[int] = []  # while planning: scan records before each
        self._recording: list[tuple[Any, ...]] | None = None  # what the planning pass reports
        self._alternatives: list[float] = []  # second stamps, collected while planning
        self._replay: list[tuple[Any, ...]] | None = None
        self._odometry_calls = 0
        self._odometry_stamps: NDArray[np.float64] | None = None  # record-order odometry stamps

    # -- what subclasses provide ------------------------------------------------------------
    @abstractmethod
    def _records(self) -> Iterator[tuple[LaserScan, str, Pose | None]]:
        """Yield ``(scan, where, reference_pose_or_None)`` in file order; ``where`` locates the
        record for messages ("line 12", "message 5"). Report unusable records with
        :meth:`_skip` and odometry with :meth:`_add_odometry`."""

    def topics(self) -> list[dict[str, Any]]:
        """The streams in the log: ``[{"name", "type", "count"}]`` (empty if not applicable)."""
        return []

    # -- helpers for subclasses -------------------------------------------------------------
    def _skip(self, reason: str, where: str, detail: str = "", count: int = 1) -> None:
        """Count ``count`` skipped records (one place, one reason); in strict mode raise
        instead."""
        if self._recording is not None:
            self._recording.append((_SKIP, reason, where, detail, count))
            return
        message = f"{where}: {reason}" + (f": {detail}" if detail else "")
        if self.strict:
            raise BadRecordError(f"{self.path}: {message}")
        self._skipped[reason] += count
        self.skip_examples.setdefault(reason, message)

    def _lines(self) -> Iterator[tuple[int, str]]:
        """``(line number, text)`` of a text log, gzip/bzip2/xz transparently; a truncated or
        corrupt compressed stream ends the iteration and is counted as :data:`TRUNCATED`."""
        lineno = 0
        try:
            with _open_text(self.path) as fh:
                for lineno, line in enumerate(fh, start=1):
                    yield lineno, line
        except (EOFError, OSError, lzma.LZMAError, zlib.error) as exc:
            self._skip(TRUNCATED, f"after line {lineno}", str(exc))

    def _add_odometry(
        self, stamp: float, pose: Pose, where: str, of_scan: bool = False
    ) -> None:
        """Keep an odometry pose; one not later than the previous is counted, never raised
        (odometry is side information: a bad record must not stop the scans). ``of_scan``: the
        pose belongs to the scan record being parsed and takes its planned stamp; otherwise,
        when the scans are read in record order, so is the odometry: it is stamped by its
        place among the scan records."""
        if self._recording is not None:
            self._recording.append((_ODOMETRY, stamp, pose, where, of_scan))
            if not of_scan:
                self._odometry_slots.append(self._produced)
            return
        if of_scan:
            stamp = self._record_stamp(stamp)
        elif self._odometry_stamps is not None:
            planned = self._odometry_stamps
            stamp = float(planned[min(self._odometry_calls, planned.size - 1)])
            self._odometry_calls += 1
        if len(self._odometry) and not stamp > self._odometry.last_stamp():
            self._skipped[ODOMETRY_NON_MONOTONIC] += 1
            self.skip_examples.setdefault(
                ODOMETRY_NON_MONOTONIC,
                f"{where}: t = {stamp:.6f} s after {self._odometry.last_stamp():.6f} s",
            )
            return
        self._odometry.append(stamp, pose)

    def _record_stamp(self, raw: float) -> float:
        """The stamp the time plan gives the scan record being parsed."""
        plan = self._plan
        if plan is None or self._produced >= plan.stamps.size:
            return raw
        return float(plan.stamps[self._produced])

    # -- time plan ----------------------------------------------------------------------------
    def _reset(self) -> None:
        self._skipped = Counter()
        self.skip_examples = {}
        self._reference = StampedPoses()
        self._odometry = StampedPoses()
        self._produced = 0
        self._odometry_calls = 0

    def _make_plan(self) -> TimePlan:
        """Read the log once and decide each scan record's stamp from all of them.

        What the reader reports while doing so (records, skips, odometry) is kept, up to
        :data:`REPLAY_BUDGET_BYTES` of ranges, so that the first iteration replays it instead
        of parsing the file again; a longer log is parsed again.
        """
        self._reset()
        self._recording = []
        self._odometry_slots = []
        stamps: list[float] = []
        budget = REPLAY_BUDGET_BYTES
        try:
            for record in self._records():
                stamps.append(record[0].stamp)
                self._produced += 1
                budget -= record[0].ranges.nbytes + 200
                if budget >= 0:
                    self._recording.append((_SCAN, *record))
                elif self._recording:  # too long to replay: what was kept goes at once
                    self._recording.clear()
            plan = plan_stamps(stamps, self._declared_period, self.reorder_window_s)
            plan = self._try_alternative(plan, len(stamps))
            if (plan.source == RECORD_ORDER or plan.alternative) and self._odometry_slots:
                self._odometry_stamps = _slot_stamps(plan, self._odometry_slots)
            self._replay = self._recording if budget >= 0 else None
        finally:
            self._recording = None
            self._odometry_slots = []
            self._alternatives = []
        return plan

    def _alternative_stamp(self, stamp: float) -> None:
        """Readers call this once per scan record they yield, with the record's second stamp
        (see :attr:`alternative_stamps`), used when its main stamps are unusable."""
        if self._recording is not None:
            self._alternatives.append(stamp)

    def _try_alternative(self, plan: TimePlan, records: int) -> TimePlan:
        """The plan of the log's second stamps when its main ones fall back to record order
        and the second ones are usable as they are (or with isolated repairs)."""
        alternative = self._alternatives
        if plan.source != RECORD_ORDER or len(alternative) != records or not records:
            return plan
        other = plan_stamps(alternative, self._declared_period, self.reorder_window_s)
        if other.source == RECORD_ORDER:
            return plan
        main_reason = plan.reason.split(";")[0]
        why = f"the main stamps are unusable: {main_reason}" + (
            f"; {other.repaired} repaired: {other.reason}" if other.repaired else "")
        return dataclasses.replace(other, alternative=self.alternative_stamps, reason=why,
                                   repaired=records)

    def _replayed(
        self, events: list[tuple[Any, ...]]
    ) -> Iterator[tuple[LaserScan, str, Pose | None]]:
        """The records of the planning pass again, with its skips and odometry reported anew
        (strict mode raises here, at the same record as a fresh parse would). Each is
        dropped from ``events`` as it is handed on, so that what the run has read is freed
        as it goes rather than held until the last scan."""
        events.reverse()
        while events:
            event = events.pop()
            if event[0] == _SCAN:
                yield event[1], event[2], event[3]
            elif event[0] == _SKIP:
                self._skip(*event[1:])
            else:
                self._add_odometry(*event[1:])

    @property
    def time_plan(self) -> TimePlan:
        """How the scans are stamped (computed on first use: reads the log's stamps)."""
        if self._plan is None:
            self._plan = self._make_plan()
            # the pass's records, freed, would stay resident under what is allocated next
            # (33 MB of a 40 Hz log's heap): handed back before the run's work
            release_free_memory()
        return self._plan

    @property
    def time_source(self) -> str:
        """Where the scans' stamps come from, for summaries: ``log stamps``, ``log stamps
        (N repaired ...)`` or ``record order at R Hz (reason)``."""
        return self.time_plan.describe()

    # -- public API -------------------------------------------------------------------------
    def __iter__(self) -> Iterator[LaserScan]:
        plan = self.time_plan
        replay, self._replay = self._replay, None  # replayed once: later passes stream again
        self._reset()
        self._complete = False
        self._iterating = True
        self._yielded = 0
        order = _Reorder(self.reorder_window_s)
        self._order = order
        try:
            for scan, where, ref in self._replayed(replay) if replay else self._records():
                k = self._produced
                self._produced += 1
                if k < plan.stamps.size and plan.stamps[k] != scan.stamp:
                    scan = dataclasses.replace(scan, stamp=float(plan.stamps[k]))
                if scan.num_beams == 0:
                    self._skip(EMPTY_SCAN, where)
                elif not order.accepts(scan.stamp):
                    self._skip(NON_MONOTONIC, where, f"t = {scan.stamp:.6f} s, "
                               f"{order.latest - scan.stamp:.6f} s before a previous scan")
                elif not scan.valid_mask.any():
                    self._skip(NO_VALID_RETURNS, where)
                else:
                    yield from self._emit(order.push(scan, ref))
            yield from self._emit(order.flush())
            self._complete = True
        finally:
            self._iterating = False

    def _emit(self, ready: list[tuple[LaserScan, Pose | None]]) -> Iterator[LaserScan]:
        for scan, ref in ready:
            if ref is not None:
                self._reference.append(scan.stamp, ref)
            self._yielded += 1
            yield scan

    def _ensure_read(self) -> None:
        """Read the log once if it was never iterated; after a partial iteration the side data
        describe the scans read so far (a caller that stopped early wants those)."""
        if self._order is None:
            for _ in self:
                pass

    @property
    def complete(self) -> bool:
        """True once an iteration has reached the end of the log."""
        return self._complete

    @property
    def scans_read(self) -> int:
        """Scans yielded so far by the current or last iteration."""
        return self._yielded

    @property
    def records_seen(self) -> int:
        """Scan records met in the file so far: those yielded plus those skipped (side records
        such as odometry, and a truncation, are not scan records). With :attr:`scans_read` it
        gives the share of a log that was read."""
        side = (ODOMETRY_NON_MONOTONIC, ODOMETRY_MALFORMED, TRUNCATED)
        return self._yielded + sum(n for r, n in self._skipped.items() if r not in side)

    @property
    def skipped(self) -> dict[str, int]:
        """Reason -> number of records skipped (complete after a full iteration)."""
        self._ensure_read()
        return dict(self._skipped)

    def read_state(self) -> ReadState:
        """The read-outs as they stand now (no reading: unlike :attr:`skipped`)."""
        return ReadState(self._yielded, self.records_seen, self._complete, dict(self._skipped),
                         dict(self.skip_examples), self.notes(), self._plan)

    def read_state_key(self) -> tuple[int, int, int]:
        """Changes whenever :meth:`read_state` would say more than one more scan read: a
        record skipped, a scan put back in order, a note of the reader (cheap, per scan)."""
        late = self._order.reordered if self._order is not None else 0
        return sum(self._skipped.values()), late, len(self._format_notes())

    @property
    def references_so_far(self) -> StampedPoses:
        """``(stamp, reference pose)`` of the scans yielded so far that carry one (no reading,
        unlike :attr:`reference`; the rows themselves, not a copy: do not change them)."""
        return self._reference

    @property
    def reference(self) -> Trajectory | None:
        """Reference (corrected) pose of each yielded scan, if the log carries one."""
        self._ensure_read()
        return self._reference.trajectory()

    @property
    def odometry(self) -> Trajectory | None:
        """Wheel odometry, if the log carries it (its own time stamps, not the scans')."""
        self._ensure_read()
        return self._odometry.trajectory()

    def _format_notes(self) -> list[str]:
        """Remarks of the format's reader (overridden by readers)."""
        return []

    def notes(self) -> list[str]:
        """Remarks about how the log was read: the reader's, a time-stamp repair or fallback,
        scans put back in order."""
        out = self.open_notes + self._format_notes()
        plan = self._plan
        if plan is not None and plan.repaired:
            out.append(f"time stamps: {plan.describe()}")
        late = self._order.reordered if self._order is not None else 0
        if late:
            out.append(f"{late} scan(s) stored out of time order were put back in order")
        return out

    def info(
        self, progress: Callable[[Iterable[LaserScan]], Iterable[LaserScan]] | None = None
    ) -> dict[str, Any]:
        """What the log holds (reads it all): the data of ``bioslam info``.

        ``progress`` may wrap the scan iterator (e.g. in a progress bar).
        """
        stats = _ScanStats()
        for scan in progress(self) if progress else self:
            stats.add(scan)
        summary: dict[str, Any] = {"format": self.format, "path": str(self.path)}
        if self.topic is not None:
            summary["topic"] = self.topic
        summary["topics"] = self.topics()
        summary.update(stats.summary())
        summary["skipped"] = dict(self._skipped)
        summary["skip_examples"] = dict(self.skip_examples)
        summary["reference_poses"] = len(self._reference)
        summary["odometry_poses"] = len(self._odometry)
        summary["notes"] = self.notes()
        summary["time_source"] = self.time_source
        return summary

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, topic={self.topic!r})"


def _slot_stamps(plan: TimePlan, slots: list[int]) -> NDArray[np.float64]:
    """Record-order stamps of side records (odometry) from the number of scan records before
    each: spread evenly between the stamps of the scans around them."""
    slot = np.asarray(slots, dtype=np.int64)
    t = plan.stamps
    before = np.concatenate(([t[0] - plan.period_s], t)) if t.size else np.zeros(1)
    after = np.concatenate((t, [t[-1] + plan.period_s])) if t.size else np.full(1, plan.period_s)
    rank = np.zeros(slot.size)
    count = np.ones(slot.size)
    starts = np.flatnonzero(np.diff(slot, prepend=-1))
    sizes = np.diff(np.append(starts, slot.size))
    for start, size in zip(starts.tolist(), sizes.tolist(), strict=True):
        rank[start : start + size] = np.arange(1, size + 1)
        count[start : start + size] = size + 1
    return before[slot] + (after[slot] - before[slot]) * rank / count


def _open_text(path: Path) -> IO[str]:
    opener = _decompressor(path)
    # latin-1 maps every byte to a character: a stray byte makes a malformed line, not a crash.
    if opener is None:
        return path.open("r", encoding="latin-1")
    return opener(path, "rt", encoding="latin-1")  # type: ignore[no-any-return]


class _Reorder:
    """Puts records that arrive a little late back in time order, for a reader whose format
    may store a stream's records out of order (``LogSource.reorder_window_s``; none of the
    readers here: a scan stamped early is a wrong stamp, repaired in its place). Records are
    held until every record that may still precede them has arrived: one more than ``window``
    seconds earlier than the latest seen is skipped as non-monotonic, as is a repeated stamp.
    """

    def __init__(self, window: float) -> None:
        self.window = window
        self.latest = -np.inf
        self.last_out = -np.inf
        self._heap: list[tuple[float, int, LaserScan, Pose | None]] = []
        self._stamps: set[float] = set()
        self._seq = 0
        self.reordered = 0  # records that arrived after a later-stamped one

    def accepts(self, stamp: float) -> bool:
        return (
            bool(np.isfinite(stamp))
            and stamp > self.last_out
            and stamp >= self.latest - self.window
            and stamp not in self._stamps
        )

    def push(self, scan: LaserScan, ref: Pose | None) -> list[tuple[LaserScan, Pose | None]]:
        if scan.stamp < self.latest:
            self.reordered += 1
        heapq.heappush(self._heap, (scan.stamp, self._seq, scan, ref))
        self._seq += 1
        self._stamps.add(scan.stamp)
        self.latest = max(self.latest, scan.stamp)
        return self._pop_until(self.latest - self.window)

    def flush(self) -> list[tuple[LaserScan, Pose | None]]:
        return self._pop_until(np.inf)

    def _pop_until(self, limit: float) -> list[tuple[LaserScan, Pose | None]]:
        out = []
        while self._heap and (self._heap[0][0] < limit or limit == np.inf):
            stamp, _, scan, ref = heapq.heappop(self._heap)
            self._stamps.discard(stamp)
            self.last_out = stamp
            out.append((scan, ref))
        return out


class StampedPoses:
    """``(stamp, x, y, theta)`` rows, 32 bytes each: a log's reference or wheel-odometry
    poses, one per scan or record (kept as a tuple each they took about 450 bytes, in the
    run and again in the reader's child: 65 MB an hour at 40 Hz)."""

    def __init__(self) -> None:
        self._rows = GrowingArray(np.float64, 4)

    def append(self, stamp: float, pose: Pose) -> None:
        self._rows.append((stamp, pose[0], pose[1], pose[2]))

    def __len__(self) -> int:
        return len(self._rows)

    def last_stamp(self) -> float:
        return float(self._rows[-1][0])

    def last_pose(self) -> Pose:
        _, x, y, theta = self._rows[-1].tolist()
        return x, y, theta

    def trajectory(self) -> Trajectory | None:
        """The rows as a trajectory; None when there are none."""
        if not len(self._rows):
            return None
        rows = self._rows.view()
        return Trajectory(rows[:, 0].copy(), rows[:, 1:].copy())


class _ScanStats:
    """Running statistics over the scans of a log, for :meth:`LogSource.info`."""

    def __init__(self) -> None:
        self.count = 0
        self.first: LaserScan | None = None
        self.last_stamp = 0.0
        self.beams: Counter[int] = Counter()
        self.range_min = np.inf
        self.range_max = -np.inf
        self.returns = 0
        self.beam_total = 0

    def add(self, scan: LaserScan) -> None:
        if self.first is None:
            self.first = scan
        self.count += 1
        self.last_stamp = scan.stamp
        self.beams[scan.num_beams] += 1
        self.range_min = min(self.range_min, scan.range_min)
        self.range_max = max(self.range_max, scan.range_max)
        self.returns += int(np.count_nonzero(scan.valid_mask))
        self.beam_total += scan.num_beams

    def summary(self) -> dict[str, Any]:
        if self.first is None:
            return {"scans": 0, "beams": 0, "fov_deg": 0.0, "duration_s": 0.0}
        first = self.first
        beams = self.beams.most_common(1)[0][0]
        duration = self.last_stamp - first.stamp
        increments = np.diff(first.angles)
        out: dict[str, Any] = {
            "scans": self.count,
            "beams": beams,
            "fov_deg": float(np.degrees(first.fov)),
            "duration_s": float(duration),
            "start_s": float(first.stamp),
            "end_s": float(self.last_stamp),
            "rate_hz": float((self.count - 1) / duration) if duration > 0 else 0.0,
            "angle_min_deg": float(np.degrees(first.angles[0])),
            "angle_max_deg": float(np.degrees(first.angles[-1])),
            "angle_increment_deg": float(np.degrees(np.mean(increments)))
            if increments.size else 0.0,
            "range_min_m": float(self.range_min),
            "range_max_m": float(self.range_max),
            "time_increment_s": float(first.time_increment),
            "valid_return_fraction": self.returns / max(self.beam_total, 1),
        }
        if len(self.beams) > 1:
            out["beam_counts"] = {str(k): v for k, v in sorted(self.beams.items())}
        return out


# -- format detection --------------------------------------------------------------------------

_EXTENSIONS = {
    ".log": "carmen",
    ".clf": "carmen",
    ".carmen": "carmen",
    ".bag": "rosbag1",
    ".db3": "rosbag2",
    ".mcap": "rosbag2",
    ".dat": "breezyslam",
}
_CARMEN_WORDS = frozenset(
    {"FLASER", "RLASER", "ROBOTLASER1", "ROBOTLASER2", "RAWLASER1", "RAWLASER2", "RAWLASER3",
     "RAWLASER4", "ODOM", "PARAM", "SYNC", "NEFF", "TRUEPOS", "POSITIONLASER"}
)


def _by_extension(path: Path) -> str | None:
    """The format a file's name suggests (a hint for messages, never the deciding word)."""
    if path.is_dir():
        return "rosbag2" if _bag_directory(path) else None
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] in (".gz", ".bz2", ".xz"):
        suffixes = suffixes[:-1]
    return _EXTENSIONS.get(suffixes[-1]) if suffixes else None


def _decompressor(path: Path) -> Any:
    """``gzip.open``/``bz2.open``/``lzma.open`` when the file starts with their magic, else None."""
    with path.open("rb") as fh:
        magic = fh.read(2)
    return {b"\x1f\x8b": gzip.open, b"BZ": bz2.open, b"\xfd7": lzma.open}.get(magic)


_HEAD_BYTES = 65536


def _head(path: Path, size: int = _HEAD_BYTES) -> bytes:
    """The first bytes of a file, decompressed when it is gzip/bzip2/xz (as much as can be:
    a truncated or corrupt compressed file gives what precedes the damage)."""
    opener = _decompressor(path) or open
    chunks: list[bytes] = []
    try:
        with opener(path, "rb") as fh:
            while sum(map(len, chunks)) < size:
                chunk = fh.read(4096)
                if not chunk:
                    break
                chunks.append(chunk)
    except (OSError, EOFError, lzma.LZMAError, zlib.error):
        pass
    return b"".join(chunks)[:size]


_IDENTIFIER = re.compile(r"[A-Z][A-Z0-9_-]*")


def _by_content(head: bytes, hint: str | None = None) -> str | None:
    """The format the first bytes of a file show, or None. Text formats are scored by the
    share of lines that look like theirs: 90 % decides alone; a damaged log of the format its
    name suggests needs half."""
    if head.startswith(b"#ROSBAG V2"):
        return "rosbag1"
    if head.startswith(b"\x89MCAP") or head.startswith(b"SQLite format 3\x00"):
        return "rosbag2"
    if b"\x00" in head:
        return None  # binary, and none of the binary formats
    lines = head.decode("latin-1").splitlines()
    if len(head) == _HEAD_BYTES and len(lines) > 1:
        lines = lines[:-1]  # the last line may be cut by the head's end
    lines = [line for line in lines if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        return None
    words = [line.split()[0] for line in lines]
    known = any(w in _CARMEN_WORDS for w in words)
    named = sum(_IDENTIFIER.fullmatch(w) is not None for w in words)
    shares = {
        "carmen": named / len(lines) if known else 0.0,
        "breezyslam": sum(_numeric_line(line) for line in lines) / len(lines),
    }
    best = max(shares, key=lambda k: shares[k])
    if shares[best] >= 0.9:
        return best
    if hint in shares and shares[hint] >= 0.5:
        return hint
    return best if shares[best] >= 0.5 else None


def _numeric_line(line: str) -> bool:
    fields = line.split()
    if len(fields) < 26:
        return False
    try:
        [float(f) for f in fields[:30]]
    except ValueError:
        return False
    return True


def _bag_directory(path: Path) -> bool:
    return (path / "metadata.yaml").exists() or any(path.glob("*.db3")) or any(
        path.glob("*.mcap")
    )


def detect_format(path: str | Path) -> str:
    """The format of ``path``, from its content; the extension only names what was expected
    when the content matches nothing.

    Raises ``FileNotFoundError`` when it does not exist and ``ValueError`` naming the file and
    listing the supported formats when it is none of them (empty, random bytes, another
    format).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    formats = "\n  ".join(f"{k}: {v}" for k, v in SUPPORTED_FORMATS.items())
    if path.is_dir():
        if _bag_directory(path):
            return "rosbag2"
        raise ValueError(f"{path}: a directory without metadata.yaml, .db3 or .mcap files is "
                         f"not a ROS 2 bag; supported formats:\n  {formats}")
    head = _head(path)
    hint = _by_extension(path)
    found = _by_content(head, hint)
    if found is not None:
        return found
    if not head.strip():
        raise ValueError(f"{path}: the file is empty (or only blank); no scans to read")
    expected = f"; its name suggests {hint}, but its content is not that" if hint else ""
    raise ValueError(f"{path}: unknown log format (content matches none of the supported "
                     f"formats{expected}); supported formats:\n  {formats}")


def open_log(
    path: str | Path, topic: str | None = None, *, strict: bool = False, fmt: str | None = None
) -> LogSource:
    """Open a LiDAR log for reading; ``fmt`` overrides format detection.

    ``topic`` chooses the scan stream when the log has several (a ROS topic, or a CARMEN
    message name such as ``ROBOTLASER1``); without it a log with several LaserScan topics is a
    ``ValueError`` that lists them.
    """
    detected = fmt is None
    fmt = fmt or detect_format(path)
    source: LogSource
    if fmt == "carmen":
        from bioslam.io.carmen import CarmenLog

        source = CarmenLog(path, topic, strict)
    elif fmt in ("rosbag1", "rosbag2"):
        from bioslam.io.rosbag import Rosbag1Log, Rosbag2Log

        source = (Rosbag1Log if fmt == "rosbag1" else Rosbag2Log)(path, topic, strict)
    elif fmt == "breezyslam":
        from bioslam.io.breezyslam import BreezySlamLog

        source = BreezySlamLog(path, topic, strict)
    else:
        raise ValueError(
            f"unknown format {fmt!r}; supported formats: {', '.join(SUPPORTED_FORMATS)}"
        )
    hint = _by_extension(Path(path))
    if detected and hint is not None and hint != fmt:
        source.open_notes.append(f"named like a {hint} log but holds a {fmt} log: read as {fmt}")
    return source
