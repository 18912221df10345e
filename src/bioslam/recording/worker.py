"""The recording's own process: it opens the MCAP file or the live server, turns the batches of
items the run sends into Foxglove messages (:class:`~.recorder.Recorder`) and closes the file.

Started by :class:`~.session.Output` as ``python -m bioslam.recording.worker`` in its own
process group (Ctrl-C in a terminal reaches the run, which stops cleanly and then tells this
process to close; it never reaches this one half-way through a write). Protocol, as pickles:
the run writes one ``spec`` dict, then batches (lists of items) and finally ``"close"`` on
stdin; this process answers ``("ready", port)`` or ``("error", text)`` after opening, and
``("closed", counts, error, cpu_seconds)`` at the end, on its stdout. If the run's process
disappears, stdin ends and the file is closed all the same.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import time
from pathlib import Path
from typing import Any, BinaryIO


def open_output(spec: dict[str, Any]) -> tuple[Any, Any, int | None]:
    """``(recorder, closer, port)`` for ``spec``: an MCAP file (``record``) or a WebSocket
    server (``live_port``, ``live_host``)."""
    import foxglove

    from bioslam.recording import rates
    from bioslam.recording.recorder import Recorder

    context = foxglove.Context()
    if spec.get("record") is not None:
        path = Path(spec["record"])
        path.parent.mkdir(parents=True, exist_ok=True)
        # zstd chunks, compressed on the SDK's own threads (as many as physical cores)
        writer = foxglove.open_mcap(path, allow_overwrite=True, context=context)
        writer.write_metadata("bioslam", spec.get("metadata", {}))
        recorder = Recorder(context, spec["odometry_only"], rates.RECORD_CONFIG, "log")
        return recorder, writer.close, None
    try:
        server = foxglove.start_server(
            name="bioslam", host=spec["live_host"], port=spec["live_port"], context=context,
            capabilities=[foxglove.Capability.Time],
        )  # fmt: skip
    except Exception as exc:  # the SDK raises its own error types
        raise RuntimeError(
            f"--live: cannot serve on {spec['live_host']}:{spec['live_port']} ({exc})"
        ) from exc
    recorder = Recorder(context, spec["odometry_only"], rates.LIVE_CONFIG, "wall",
                        on_time=server.broadcast_time)  # fmt: skip
    return recorder, server.stop, server.port


def serve(requests: BinaryIO, replies: BinaryIO) -> None:
    """Open the output the first request describes, publish every batch, close."""
    started = time.process_time()
    spec = pickle.load(requests)
    try:
        recorder, closer, port = open_output(spec)
    except Exception as exc:
        _reply(replies, ("error", str(exc) if isinstance(exc, RuntimeError)
                         else f"{type(exc).__name__}: {exc}"))  # fmt: skip
        return
    _reply(replies, ("ready", port))
    error = None
    try:
        while True:
            try:
                batch = pickle.load(requests)
            except EOFError:  # the run's process is gone: close the file all the same
                break
            if batch == "close":
                break
            recorder.handle(batch)
    except Exception as exc:  # reported to the run, which goes on without recording
        error = f"{type(exc).__name__}: {exc}"
    finally:
        closer()
    _reply(replies, ("closed", recorder.counts, error, time.process_time() - started))


def _reply(replies: BinaryIO, message: Any) -> None:
    try:
        pickle.dump(message, replies)
        replies.flush()
    except (BrokenPipeError, OSError):
        pass  # nobody listens any more


def main() -> None:
    # A signal is the run's to handle; this process closes when the run says so.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    replies = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # stray prints must not corrupt replies
    serve(sys.stdin.buffer, replies)


if __name__ == "__main__":
    main()
