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

The child ignores SIGINT and SIGTERM (the command decides what a signal means: a Ctrl-C
reaches the whole process group), dies with its parent, and is killed by :meth:`close` when
the run stops early. Where there is no ``fork`` or a single core, :func:`read_ahead` returns
the source itself.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import pickle
import signal
from collections.abc import Iterator
from types import TracebackType
from typing import IO, Any

from bioslam.io.logs import LogSource, Pose, ReadState, _trajectory
from bioslam.io.timestamps import TimePlan
from bioslam.scan import LaserScan
from bioslam.trajectory import Trajectory

#: Scans a message carries: large enough that pickling costs little per scan (the angles an
#: unchanged sensor shares are sent once a batch), small enough that the first scan comes
#: soon and that little is held in the pipe (64 scans of 1081 beams: 350 kB).
BATCH_SCANS = 64
#: Bytes the pipe may hold (Linux allows up to 1 MiB to anyone): about three batches.
PIPE_BYTES = 2**20
_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_PR_SET_PDEATHSIG = 1
_MAX_FD = 65536


def cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def read_ahead(source: LogSource) -> ReadAhead | LogSource:
    """``source`` read in a child process (:class:`ReadAhead`) where that can gain time (a
    second core and ``fork``), else ``source`` itself."""
    if not hasattr(os, "fork") or cores() < 2:
        return source
    return ReadAhead(source)


class ReadAhead:
    """A :class:`LogSource` iterated in a child process (module doc); iterate it once, then
    :meth:`close` it (or use it as a context manager). Its read-outs are the source's."""

    def __init__(self, source: LogSource, batch: int = BATCH_SCANS) -> None:
        self.source = source
        self.path, self.format, self.topic = source.path, source.format, source.topic
        self._state = ReadState(0, 0, False, {}, {}, source.notes(), None)
        self._consumed = 0
        self._references: list[tuple[float, Pose]] = []
        self._iterated = False
        self._pid: int | None = None
        self._pipe: IO[bytes] | None = None
        self._start(batch)

    # -- the child ------------------------------------------------------------------------------
    def _start(self, batch: int) -> None:
        read_end, write_end = os.pipe()
        _widen(write_end)
        # No signal between the fork and the child's ignoring it: the parent's handlers
        # would run in the child and raise there.
        parent = os.getpid()
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
        try:
            pid = os.fork()
            if pid == 0:  # the child: never returns
                os.close(read_end)
                _child(self.source, write_end, batch, parent)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        os.close(write_end)
        self._pid = pid
        self._pipe = os.fdopen(read_end, "rb")

    # -- iteration ------------------------------------------------------------------------------
    def __iter__(self) -> Iterator[LaserScan]:
        if self._iterated:
            raise RuntimeError(f"{self.path}: a read-ahead log is read once")
        self._iterated = True
        pipe = self._pipe
        if pipe is None:
            raise RuntimeError(f"{self.path}: the read-ahead log was closed")
        while True:
            try:
                items = pickle.load(pipe)
            except (EOFError, pickle.UnpicklingError, OSError) as exc:
                raise RuntimeError(f"{self.path}: the reading process ended early "
                                   f"({type(exc).__name__})") from None
            for item in items:
                if isinstance(item, ReadState):
                    self._state = item
                elif isinstance(item, tuple):
                    scan, ref = item
                    self._consumed += 1
                    if ref is not None:
                        self._references.append((scan.stamp, ref))
                    yield scan
                elif isinstance(item, BaseException):
                    raise item
                else:  # the end
                    self.close()
                    return

    def close(self) -> None:
        """Stop the child (if it is still reading) and reap it."""
        if self._pipe is not None:
            self._pipe.close()
            self._pipe = None
        if self._pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self._pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError):
                os.waitpid(self._pid, 0)
            self._pid = None

    def __enter__(self) -> ReadAhead:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

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
        return _trajectory(self._references)

    @property
    def time_plan(self) -> TimePlan:
        """The child's plan; before its first scan arrived, the source's own (which reads
        the log's stamps here, as the source would)."""
        return self._state.time_plan or self.source.time_plan

    @property
    def time_source(self) -> str:
        return self.time_plan.describe()


def _child(source: LogSource, fd: int, batch: int, parent: int) -> None:
    """Iterate ``source``, sending batches of scans and read-out snapshots to ``fd``; exit."""
    code = 0
    try:
        for sig in _SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)
        # the parent's other pipes (a recorder's, a subprocess's) must see their end when
        # the parent closes them, not when this child exits: only the sources' own files
        # (opened as they are read) and the standard streams are used here
        os.closerange(3, fd)
        os.closerange(fd + 1, _MAX_FD)
        _die_with_parent()
        if os.getppid() != parent:  # it ended before the request
            return
        with os.fdopen(fd, "wb") as pipe:
            _send_scans(source, pipe, batch)
    except BaseException:  # a child must never return into the parent's code
        code = 1
    finally:
        os._exit(code)


def _send_scans(source: LogSource, pipe: IO[bytes], batch: int) -> None:
    items: list[Any] = []
    key: tuple[int, ...] | None = None
    taken = 0
    scans = 0

    def send() -> None:
        pickle.dump(items, pipe, protocol=pickle.HIGHEST_PROTOCOL)
        pipe.flush()
        items.clear()

    try:
        for scan in source:
            now = source.read_state_key()
            if now != key:
                key = now
                items.append(source.read_state())
            references = source.references_so_far  # a new list for each iteration
            ref = references[-1][1] if len(references) > taken else None
            taken = len(references)
            items.append((scan, ref))
            scans += 1
            if scans % batch == 0:
                send()
        items.append(source.read_state())
        items.append(None)
    except Exception as exc:
        items.append(source.read_state())
        items.append(_picklable(exc))
    send()


def _picklable(exc: Exception) -> Exception:
    """``exc`` if it survives pickling, else a RuntimeError that says the same."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _widen(fd: int) -> None:
    """Let the pipe hold a few batches (Linux: 64 kB by default, less than one): the child
    then writes ahead while the parent works, and the parent finds a whole batch waiting
    instead of waking the child for every 64 kB of it."""
    with contextlib.suppress(Exception):
        import fcntl  # POSIX only, as is fork

        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)


def _die_with_parent() -> None:
    """Ask Linux to kill this process when its parent ends (elsewhere: the pipe's closing
    ends it at its next write)."""
    with contextlib.suppress(Exception):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
