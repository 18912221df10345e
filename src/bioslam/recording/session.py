"""``--record OUT.mcap`` and ``--live [PORT]`` for a command: the arguments, and a session that
opens the file and the server, feeds the run to them and always closes them.

Importing this module costs nothing: the Foxglove SDK is imported only when a session opens
with something to do, so a run without these flags never loads it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import TracebackType
from typing import Any

from bioslam.geometry import Pose2D
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


class Session:
    """The recording and the live view a command asked for, used as ``with Session(...) as s``.

    ``observer`` is the pipeline's per-scan observer (None when nothing was asked for, so the
    run does not even call it); :meth:`finish` publishes the final state; leaving the ``with``
    block closes the MCAP file (it is complete and readable even after an interrupted or failed
    run) and stops the server.
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
        self.odometry_only = odometry_only
        self.metadata = metadata or {}
        self.announce = announce
        self.recorders: list[Any] = []
        self.writer: Any = None
        self.server: Any = None
        self.port: int | None = None
        self.error: str | None = None

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
        return self.record is not None or self.live_port is not None

    @property
    def observer(self) -> Session | None:
        return self if self.active else None

    def __enter__(self) -> Session:
        if not self.active:
            return self
        try:
            self._open()
        except BaseException:
            self.close()
            raise
        return self

    def _open(self) -> None:
        try:
            import foxglove

            from bioslam.recording import recorder as rec
        except ImportError as exc:
            raise RuntimeError(MISSING_SDK) from exc
        if self.record is not None:
            context = foxglove.Context()
            self.record.parent.mkdir(parents=True, exist_ok=True)
            # zstd chunks, compressed on the SDK's own threads (as many as physical cores)
            self.writer = foxglove.open_mcap(self.record, allow_overwrite=True, context=context)
            self.writer.write_metadata("bioslam", self.metadata)
            self.recorders.append(rec.Recorder(context, self.odometry_only, rec.RECORD_CONFIG))
        if self.live_port is not None:
            context = foxglove.Context()
            try:
                self.server = foxglove.start_server(
                    name="bioslam", host=self.live_host, port=self.live_port, context=context,
                    capabilities=[foxglove.Capability.Time],
                )  # fmt: skip
            except Exception as exc:  # the SDK raises its own error types
                raise RuntimeError(
                    f"--live: cannot serve on {self.live_host}:{self.live_port} ({exc})"
                ) from exc
            self.port = self.server.port
            self.recorders.append(
                rec.Recorder(context, self.odometry_only, rec.LIVE_CONFIG, clock="wall",
                             on_time=self.server.broadcast_time)
            )  # fmt: skip
            if self.announce:
                print(f"live view: connect Foxglove to {self.url} "
                      "(Open connection > Foxglove WebSocket)", file=sys.stderr, flush=True)

    @property
    def url(self) -> str | None:
        """The live server's WebSocket address, once it runs."""
        if self.port is None:
            return None
        return f"ws://{self.live_host}:{self.port}"

    def __call__(self, scan: LaserScan, pose: Pose2D, system: Any) -> None:
        for recorder in self.recorders:
            recorder(scan, pose, system)

    def finish(self, system: Any) -> None:
        """Publish the final map, cognitive map and trajectory (after the system settled).
        A failure here is reported in :meth:`summary`, never raised: the run's own results
        come first."""
        for recorder in self.recorders:
            try:
                recorder.finish(system)
            except Exception as exc:
                self.error = f"{type(exc).__name__}: {exc}"
                print(f"bioslam: recording: {self.error}", file=sys.stderr)

    def close(self) -> None:
        """Close the file and stop the server; safe to call more than once."""
        writer, self.writer = self.writer, None
        server, self.server = self.server, None
        try:
            if writer is not None:
                writer.close()
        finally:
            if server is not None:
                server.stop()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def summary(self) -> dict[str, Any]:
        """What was recorded or served, for the run's summary."""
        out: dict[str, Any] = {}
        for recorder in self.recorders:
            key = "recording" if recorder.clock == "log" else "live"
            out[key] = {"messages": sum(recorder.counts.values()),
                        "seconds": round(recorder.seconds, 3),
                        "cpu_seconds": round(recorder.cpu_seconds, 3)}  # fmt: skip
        if "recording" in out and self.record is not None and self.record.exists():
            out["recording"]["path"] = str(self.record)
            out["recording"]["bytes"] = self.record.stat().st_size
        if "live" in out:
            out["live"]["url"] = self.url
        if self.error and out:
            next(iter(out.values()))["error"] = self.error
        return out
