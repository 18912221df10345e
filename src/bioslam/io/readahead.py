"""Reading a log in a child process, ahead of the run that consumes its scans.

Parsing a log costs a run CPU time that is not the SLAM's: on the 600 s simulated 40 Hz route
(24,000 scans of 1081 beams in a ROS 2 bag) the time plan's pass over the stamps and the
read itself take about 2.5 s of the process's 27 s. :class:`ReadAhead` forks a child that
iterates the :class:`~bioslam.io.logs.LogSource` (time plan, repairs, skips, reordering: all
of it, unchanged) and hands the scans over a pipe in batches, so that on a machine with a
second core the reading runs beside the per-scan work instead of between the scans.

The run sees the same scans in the same order, bit for bit, and the same read-outs (scans
read, records met, skips with their first example, notes, the reference poses, the time
source) as the source itself would give *at the scan the run has reached*: the child sends a
snapshot of its read-outs whenever one changes, between the scans, and the parent applies each
when it takes the next scan. A run interrupted half-way therefore reports what it read, not
what the child had read ahead. An exception the source raises (a strict read's bad record)
is raised in the parent at the same scan.

The child is a :class:`bioslam.io.forked.Forked` helper (it ignores signals, dies with its
parent) and is killed by :meth:`ReadAhead.close` when the run stops early. Where there is no
``fork`` or a single core, :func:`read_ahead` returns the source itself.
"""

from __future__ import annotations

import functools
import pickle
from collections.abc import Iterator
from typing import Any

from bioslam.io.forked import Channel, ChildEndedError, Forked, Helper, can_fork
from bioslam.io.logs import LogSource, ReadState, StampedPoses
from bioslam.io.timestamps import TimePlan
from bioslam.scan import LaserScan
from bioslam.trajectory import Trajectory

#: Scans a message carries: large enough that pickling costs little per scan (the angles an
#: unchanged sensor shares are sent once a batch), small enough that the first scan comes
#: soon and that little is held in the pipe (64 scans of 1081 beams: 350 kB).
BATCH_SCANS = 64


def read_ahead(source: LogSource) -> ReadAhead | LogSource:
    """``source`` read in a child process (:class:`ReadAhead`) where that can gain time (a
    second core and ``fork``), else ``source`` itself."""
    return ReadAhead(source) if can_fork() else source


class ReadAhead(Helper):
    """A :class:`LogSource` iterated in a child process (module doc); iterate it once, then
    :meth:`close` it (or use it as a context manager). Its read-outs are the source's."""

    def __init__(self, source: LogSource, batch: int = BATCH_SCANS) -> None:
        self.source = source
        self.path, self.format, self.topic = source.path, source.format, source.topic
        self._state = ReadState(0, 0, False, {}, {}, source.notes(), None)
        self._consumed = 0
        self._references = StampedPoses()
        self._iterated = False
        self._child = Forked(functools.partial(_send_scans, source, batch))

    # -- iteration ------------------------------------------------------------------------------
    def __iter__(self) -> Iterator[LaserScan]:
        if self._iterated:
            raise RuntimeError(f"{self.path}: a read-ahead log is read once")
        self._iterated = True
        while True:
            try:
                items = self._child.receive()
            except ChildEndedError as exc:
                raise ChildEndedError(f"{self.path}: reading the log: {exc}") from None
            for item in items:
                if isinstance(item, ReadState):
                    self._state = item
                elif isinstance(item, tuple):
                    scan, ref = item
                    self._consumed += 1
                    if ref is not None:
                        self._references.append(scan.stamp, ref)
                    yield scan
                elif isinstance(item, BaseException):
                    raise item
                else:  # the end
                    self.close()
                    return

    # -- read-outs (LogSource's, as at the last scan taken) -------------------------------------
    @property
    def scans_read(self) -> int:
        return self._consumed

    @property
    def records_seen(self) -> int:
        state = self._state
        return state.records_seen - state.scans_read + self._consumed

    @property
    def complete(self) -> bool:
        return self._state.complete

    @property
    def skipped(self) -> dict[str, int]:
        return dict(self._state.skipped)

    @property
    def skip_examples(self) -> dict[str, str]:
        return dict(self._state.skip_examples)

    def notes(self) -> list[str]:
        return list(self._state.notes)

    @property
    def reference(self) -> Trajectory | None:
        return self._references.trajectory()

    @property
    def time_plan(self) -> TimePlan:
        """The child's plan; before its first scan arrived, the source's own (which reads
        the log's stamps here, as the source would)."""
        return self._state.time_plan or self.source.time_plan

    @property
    def time_source(self) -> str:
        return self.time_plan.describe()


def _send_scans(source: LogSource, batch: int, channel: Channel) -> None:
    """In the child: iterate ``source``, sending batches of scans (each with its reference
    pose) and, before a scan, the read-outs whenever they changed; then the last read-outs
    and the end (None) or the exception the source raised."""
    items: list[Any] = []
    key: tuple[int, ...] | None = None
    taken = 0
    scans = 0
    try:
        source.time_plan  # noqa: B018 - the pass over the stamps, before the first scan
        for scan in source:
            now = source.read_state_key()
            if now != key:
                key = now
                items.append(source.read_state())
            references = source.references_so_far  # new rows for each iteration
            ref = references.last_pose() if len(references) > taken else None
            taken = len(references)
            items.append((scan, ref))
            scans += 1
            if scans % batch == 0:
                channel.send(items)
                items = []
        items += [source.read_state(), None]
    except Exception as exc:
        items += [source.read_state(), _picklable(exc)]
    channel.send(items)


def _picklable(exc: Exception) -> Exception:
    """``exc`` if it survives pickling, else a RuntimeError that says the same."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc
