"""Reading a recording back with the ``mcap`` reader: an ``mcap info``-style summary, the log
times per channel, and decoded messages (protobuf through ``mcap-protobuf-support``, JSON).

    python -m bioslam.recording.reading RUN.mcap     # prints the summary
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from numpy.typing import NDArray


@dataclass(frozen=True)
class ChannelInfo:
    """One channel of a recording, as ``mcap info`` lists it."""

    topic: str
    schema: str
    schema_encoding: str
    message_encoding: str
    messages: int


@dataclass(frozen=True)
class RecordingSummary:
    """What the MCAP summary section says about a file."""

    path: str
    bytes: int
    profile: str
    library: str
    messages: int
    start_ns: int
    end_ns: int
    chunks: int
    compression: tuple[str, ...]
    channels: tuple[ChannelInfo, ...]
    metadata: dict[str, dict[str, str]]

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9

    def counts(self) -> dict[str, int]:
        return {c.topic: c.messages for c in self.channels}

    def schemas(self) -> dict[str, str]:
        return {c.topic: c.schema for c in self.channels}


def summarize(path: str | Path) -> RecordingSummary:
    """Read the summary section (no message is decoded); a file without one (a writer that
    never closed) is an error naming the file."""
    path = Path(path)
    with path.open("rb") as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            raise ValueError(f"{path}: no MCAP summary section (was the file closed?)")
        stats = summary.statistics
        channels = []
        for cid, channel in sorted(summary.channels.items()):
            schema = summary.schemas.get(channel.schema_id)
            channels.append(ChannelInfo(
                topic=channel.topic,
                schema=schema.name if schema else "",
                schema_encoding=schema.encoding if schema else "",
                message_encoding=channel.message_encoding,
                messages=stats.channel_message_counts.get(cid, 0),
            ))  # fmt: skip
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        return RecordingSummary(
            path=str(path),
            bytes=path.stat().st_size,
            profile=header.profile,
            library=header.library,
            messages=stats.message_count,
            start_ns=stats.message_start_time,
            end_ns=stats.message_end_time,
            chunks=stats.chunk_count,
            compression=tuple(sorted({c.compression for c in summary.chunk_indexes})),
            channels=tuple(channels),
            metadata=metadata,
        )


def format_summary(info: RecordingSummary) -> str:
    """The summary as ``mcap info`` prints it: file, times, chunks, then one line per channel."""
    width = max((len(c.topic) for c in info.channels), default=0)
    lines = [
        f"file:        {info.path} ({info.bytes / 1e6:.2f} MB)",
        f"library:     {info.library}",
        f"messages:    {info.messages}",
        f"duration:    {info.duration_s:.3f} s",
        f"start:       {info.start_ns / 1e9:.3f}",
        f"end:         {info.end_ns / 1e9:.3f}",
        f"chunks:      {info.chunks} ({', '.join(info.compression) or 'uncompressed'})",
        f"channels:    {len(info.channels)}",
    ]
    for c in info.channels:
        lines.append(
            f"  {c.topic:<{width}}  {c.messages:>7} msgs  : {c.schema} "
            f"[{c.schema_encoding}] ({c.message_encoding})"
        )
    return "\n".join(lines)


def log_times(path: str | Path) -> dict[str, NDArray[np.int64]]:
    """The log times (ns) of every message per topic, in the order the file holds them."""
    times: dict[str, list[int]] = {}
    with Path(path).open("rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages():
            times.setdefault(channel.topic, []).append(message.log_time)
    return {topic: np.asarray(t, dtype=np.int64) for topic, t in times.items()}


class _JsonDecoderFactory(McapDecoderFactory):
    """JSON messages (``message_encoding`` json) decode to dicts."""

    def decoder_for(self, message_encoding: str, schema: Any) -> Any:
        return json.loads if message_encoding == "json" else None


def decoded_messages(
    path: str | Path, topics: Iterable[str] | None = None
) -> Iterator[tuple[str, int, Any]]:
    """``(topic, log_time_ns, message)`` in log-time order: protobuf messages as generated
    classes, JSON messages as dicts."""
    with Path(path).open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory(), _JsonDecoderFactory()])
        wanted = None if topics is None else list(topics)
        for _, channel, message, decoded in reader.iter_decoded_messages(topics=wanted):
            yield channel.topic, message.log_time, decoded


def last_message(path: str | Path, topic: str) -> Any:
    """The last message on ``topic`` (None if there is none)."""
    last = None
    for _, _, message in decoded_messages(path, [topic]):
        last = message
    return last


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Summarise an MCAP recording (mcap info).")
    parser.add_argument("file", type=Path)
    args = parser.parse_args(argv)
    print(format_summary(summarize(args.file)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
