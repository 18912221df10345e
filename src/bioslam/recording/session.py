"""``--record OUT.mcap`` and ``--live [PORT]`` for a command: the arguments, and a session that
starts the recording process(es), feeds the run to them and always closes them.

Each output (the file, the server) has its own process (:mod:`.worker`) that builds and writes
the messages; the run only copies out what they need (:class:`~.tap.Tap`) and sends it down a
pipe, so recording costs the run little, and the file is closed properly whatever happens to
the run (an interrupted run, a failed one, even a killed one: the worker sees its input end).
Importing this module costs nothing (building a command's parser imports it): the system's
modules are imported when an output is asked for, the Foxglove SDK only by the workers.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import pickle
import queue
import subprocess
import sys
import threading
from pathlib import Path
from types import TracebackType
from typing import Any

import bioslam
from bioslam.geometry import Pose2D
from bioslam.recording.rates import LIVE_CONFIG, RECORD_CONFIG
from bioslam.scan import LaserScan

DEFAULT_PORT = 8765
DEFAULT_HOST = "127.0.0.1"
MISSING_SDK = (
    "--record and --live need the optional Foxglove packages: pip install 'bioslam[foxglove]'"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The recording and live-view options of a command that runs the system."""
    group = parser.add_argument_group("watching a run in Foxglove")
    group.add_argument(
        "--record", type=Path, metavar="OUT.mcap",
        help="write scans, poses, transforms, maps, neurons and log messages to an MCAP file",
    )  # fmt: skip
    group.add_argument(
        "--live", type=int, nargs="?", const=DEFAULT_PORT, metavar="PORT",
        help=f"serve the same channels to Foxglove over WebSocket while the run goes "
        f"(default port {DEFAULT_PORT}; 0 picks a free one)",
    )  # fmt: skip
    group.add_argument(
        "--live-host", default=DEFAULT_HOST, metavar="ADDRESS",
        help=f"address the live server binds to (default {DEFAULT_HOST}: this machine only)",
    )  # fmt: skip


class Output:
    """One output (an MCAP file or a live server) in its own process, fed by a :class:`Tap`.

    A thread of the run's process writes the tap's batches down the pipe, so that the run
    never waits on the worker while fewer than :data:`QUEUE` batches are pending. Then a
    recording waits (it keeps every scan); a live view drops the batch and counts it (a
    viewer wants the present, and the run must not slow down for it).
    """

    #: seconds to wait for the worker to open its output, and to close it
    TIMEOUT = 300.0
    #: batches that may wait for the worker
    QUEUE = 256

    def __init__(self, spec: dict[str, Any], live: bool) -> None:
        from bioslam.recording.tap import Tap  # the SLAM system's modules: only when used

        self.spec = spec
        self.kind = "live" if live else "recording"
        self.tap = Tap(self._send, LIVE_CONFIG if live else RECORD_CONFIG,
                       "wall" if live else "log")  # fmt: skip
        self.process: subprocess.Popen | None = None
        self.port: int | None = None
        self.counts: dict[str, int] = {}
        self.error: str | None = None
        self.worker_cpu_seconds = 0.0
        self.live = live
        #: items a live view dropped because its worker was behind
        self.dropped = 0
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=self.QUEUE)
        self._pump: threading.Thread | None = None

    def open(self) -> None:
        env = dict(os.environ)
        # the worker imports this very bioslam, installed or not
        package_root = str(Path(bioslam.__file__).resolve().parents[1])
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [package_root, env.get("PYTHONPATH")]))
        self.process = subprocess.Popen(
            [sys.executable, "-m", "bioslam.recording.worker"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, start_new_session=True,
        )  # fmt: skip
        self._write(self.spec)
        reply = self._read()
        if reply is None or reply[0] != "ready":
            self._reap()
            text = reply[1] if reply else "the recording process ended before it started"
            if "No module named 'foxglove'" in text or "No module named 'mcap'" in text:
                text = MISSING_SDK
            raise RuntimeError(text)
        self.port = reply[1]
        self._pump = threading.Thread(target=self._pumping, name=f"bioslam-{self.kind}",
                                      daemon=True)  # fmt: skip
        self._pump.start()

    def _pumping(self) -> None:
        """The writing thread: batches down the pipe until the ``None`` that ends them."""
        while (batch := self._queue.get()) is not None:
            try:
                self._write(batch)
            except (BrokenPipeError, OSError) as exc:
                self.error = f"the {self.kind} process stopped ({exc}); the run goes on without it"
                print(f"bioslam: {self.error}", file=sys.stderr)
                return

    def _enqueue(self, item: Any, wait: bool) -> bool:
        """Queue ``item`` for the writing thread; without ``wait`` give up at once when the
        queue is full. False when it was not queued."""
        while self.error is None and self._pump is not None and self._pump.is_alive():
            try:
                if wait:
                    self._queue.put(item, timeout=1.0)
                else:
                    self._queue.put_nowait(item)
                return True
            except queue.Full:
                if not wait:
                    return False
        return False

    def _write(self, message: Any) -> None:
        assert self.process is not None and self.process.stdin is not None
        pickle.dump(message, self.process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
        self.process.stdin.flush()

    def _read(self) -> Any:
        assert self.process is not None and self.process.stdout is not None
        try:
            return pickle.load(self.process.stdout)
        except (EOFError, pickle.UnpicklingError):
            return None

    def _send(self, batch: list) -> None:
        if self.process is None or self.error is not None:
            return
        if not self._enqueue(batch, wait=not self.live) and self.live:
            self.dropped += len(batch)

    def close(self) -> None:
        """Tell the worker to close its output and wait for it; safe to call again."""
        if self.process is None:
            return
        self.tap.flush()
        if self._pump is not None:
            self._enqueue(None, wait=True)
            self._pump.join()
            self._pump = None
        if self.error is None:
            try:
                self._write("close")
            except (BrokenPipeError, OSError) as exc:
                self.error = f"the {self.kind} process stopped ({exc})"
        if self.process.stdin is not None:
            with contextlib.suppress(OSError):
                self.process.stdin.close()
        reply = self._read()
        if reply is not None and reply[0] == "closed":
            _, self.counts, error, self.worker_cpu_seconds = reply
            self.error = self.error or error
        elif self.error is None:
            self.error = f"the {self.kind} process ended without closing its output"
        self._reap()

    def _reap(self) -> None:
        process, self.process = self.process, None
        if process is None:
            return
        try:
            process.wait(timeout=self.TIMEOUT)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        for stream in (process.stdin, process.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()


class Session:
    """The recording and the live view a command asked for, used as ``with Session(...) as s``.

    ``observer`` is the pipeline's per-scan observer (None when nothing was asked for, so the
    run does not even call it); :meth:`finish` sends the final state; leaving the ``with``
    block closes the MCAP file (complete and readable even after an interrupted or failed run)
    and stops the server.
    """

    def __init__(
        self,
        record: Path | None = None,
        live_port: int | None = None,
        live_host: str = DEFAULT_HOST,
        odometry_only: bool = False,
        metadata: dict[str, str] | None = None,
        announce: bool = True,
    ) -> None:
        if record is not None and record.is_dir():
            raise ValueError(f"--record {record}: is a directory; give a file name (OUT.mcap)")
        if live_port is not None and not 0 <= live_port <= 65535:
            raise ValueError(f"--live {live_port}: not a port number (0-65535)")
        self.record = record
        self.live_port = live_port
        self.live_host = live_host
        self.announce = announce
        self.outputs: list[Output] = []
        common = {"odometry_only": odometry_only, "metadata": dict(metadata or {})}
        if record is not None:
            self.outputs.append(Output({**common, "record": str(record)}, live=False))
        if live_port is not None:
            spec = {**common, "live_port": live_port, "live_host": live_host}
            self.outputs.append(Output(spec, live=True))

    @classmethod
    def from_args(cls, args: argparse.Namespace, odometry_only: bool, **metadata: Any) -> Session:
        """The session a command's ``--record``/``--live``/``--live-host`` ask for; ``metadata``
        (e.g. ``input=PATH``) goes into the recording's ``bioslam`` metadata record."""
        return cls(
            args.record, args.live, args.live_host, odometry_only,
            {key: str(value) for key, value in metadata.items()},
        )  # fmt: skip

    @property
    def active(self) -> bool:
        return bool(self.outputs)

    @property
    def observer(self) -> Session | None:
        return self if self.active else None

    @property
    def port(self) -> int | None:
        """The live server's port, once it runs."""
        return next((o.port for o in self.outputs if o.kind == "live"), None)

    @property
    def url(self) -> str | None:
        """The live server's WebSocket address, once it runs."""
        return None if self.port is None else f"ws://{self.live_host}:{self.port}"

    def counts(self, kind: str = "recording") -> dict[str, int]:
        """Messages per topic that the recording (or live view) published, once closed."""
        return next((o.counts for o in self.outputs if o.kind == kind), {})

    def __enter__(self) -> Session:
        try:
            for output in self.outputs:
                output.open()
        except BaseException:
            self.close()
            raise
        if self.url and self.announce:
            print(f"live view: connect Foxglove to {self.url} "
                  "(Open connection > Foxglove WebSocket)", file=sys.stderr, flush=True)
        return self

    def __call__(self, scan: LaserScan, pose: Pose2D, system: Any) -> None:
        for output in self.outputs:
            output.tap(scan, pose, system)

    def finish(self, system: Any) -> None:
        """Send the final map, cognitive map and trajectory (after the system settled). A
        failure here is reported in :meth:`summary`, never raised: the run's results come
        first."""
        for output in self.outputs:
            try:
                output.tap.finish(system)
            except Exception as exc:
                output.error = f"{type(exc).__name__}: {exc}"
                print(f"bioslam: {output.kind}: {output.error}", file=sys.stderr)

    def close(self) -> None:
        """Close the file and stop the server (waiting for the workers); safe to repeat."""
        for output in self.outputs:
            output.close()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def summary(self) -> dict[str, Any]:
        """What was recorded or served, for the run's summary: messages, the run's seconds
        in the tap (wall and CPU) and the worker's CPU seconds."""
        out: dict[str, Any] = {}
        for output in self.outputs:
            part: dict[str, Any] = {
                "messages": sum(output.counts.values()),
                "run_seconds": round(output.tap.seconds, 3),
                "run_cpu_seconds": round(output.tap.cpu_seconds, 3),
                "worker_cpu_seconds": round(output.worker_cpu_seconds, 3),
            }
            if output.kind == "recording" and self.record is not None and self.record.exists():
                part["path"] = str(self.record)
                part["bytes"] = self.record.stat().st_size
            if output.kind == "live":
                part["url"] = self.url
                part["dropped"] = output.dropped
            if output.error:
                part["error"] = output.error
            out[output.kind] = part
        return out
