"""ROS 1 and ROS 2 bags holding ``sensor_msgs/LaserScan``, read through ``rosbags``.

The scan topic is auto-detected when the bag has exactly one LaserScan topic. Scans are stamped
with ``header.stamp`` (the bag's receive time when the header is zero) and keep the message's
``time_increment``.

Some ROS 1 bags carry an index that ``rosbags`` rejects (``laser_scan_matcher_demo.bag``: its
index-data records are not the 12 bytes per entry the format specifies), and truncated bags have
no index at all. Those are read by :class:`Bag1RecordReader`, which walks the bag's records in
file order (bag header, chunks, connections, message data) and ignores the index.
"""

from __future__ import annotations

import bisect
import bz2
import mmap
import struct
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bioslam.io.logs import DAMAGED, MALFORMED, TRUNCATED, WRONG_BEAM_COUNT, LogSource, Pose
from bioslam.scan import LaserScan

LASERSCAN = "sensor_msgs/msg/LaserScan"
# A message's beam count may differ by one from (angle_max - angle_min) / angle_increment + 1:
# drivers disagree on whether angle_max is included.
_BEAM_COUNT_SLACK = 1


def normalize_msgtype(name: str) -> str:
    """``sensor_msgs/LaserScan`` (ROS 1) -> ``sensor_msgs/msg/LaserScan`` (ROS 2 spelling)."""
    parts = name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name


@lru_cache(maxsize=2)
def _typestore(ros1: bool) -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


# -- LaserScan message -> LaserScan ---------------------------------------------------------------

class _ScanConverter:
    """Builds LaserScans from deserialised messages, checking them and caching beam angles."""

    def __init__(self, source: LogSource) -> None:
        self.source = source
        self._angles: dict[tuple[float, float, int], NDArray[np.float64]] = {}

    def __call__(self, msg: Any, bag_time_ns: int, where: str) -> LaserScan | None:
        ranges = np.asarray(msg.ranges, dtype=np.float32)
        n = ranges.size
        a_min, a_max, inc = float(msg.angle_min), float(msg.angle_max), float(msg.angle_increment)
        if not (np.isfinite([a_min, a_max, inc]).all() and inc != 0.0):
            self.source._skip(MALFORMED, where, f"bad angles: min {a_min}, max {a_max}, "
                              f"increment {inc}")
            return None
        if n:
            expected = round((a_max - a_min) / inc) + 1
            if abs(n - expected) > _BEAM_COUNT_SLACK:
                self.source._skip(WRONG_BEAM_COUNT, where, f"{n} ranges but the angles describe "
                                  f"{expected} beams")
                return None
        scan_time = float(msg.scan_time)
        if self.source._declared_period is None and np.isfinite(scan_time) and scan_time > 0:
            self.source._declared_period = scan_time
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        if stamp == 0.0:
            stamp = bag_time_ns * 1e-9
        key = (a_min, inc, n)
        angles = self._angles.get(key)
        if angles is None:
            angles = a_min + inc * np.arange(n, dtype=np.float64)
            self._angles[key] = angles
        return LaserScan(stamp, ranges, angles, float(msg.range_min), float(msg.range_max),
                         float(msg.time_increment))


@dataclass(frozen=True)
class TopicEntry:
    """One topic of a bag."""

    name: str
    msgtype: str
    count: int


def choose_scan_topic(path: Path, topics: list[TopicEntry], wanted: str | None) -> str:
    """The LaserScan topic to read: ``wanted`` (with or without leading '/'), else the only one.

    Raises ``ValueError`` listing the candidates when there are none, several, or ``wanted`` is
    not one of them.
    """
    candidates = [t.name for t in topics if t.msgtype == LASERSCAN]
    listing = ", ".join(candidates) if candidates else "none"
    if wanted is not None:
        for name in (wanted, "/" + wanted.lstrip("/")):
            if name in candidates:
                return name
        others = ", ".join(f"{t.name} ({t.msgtype})" for t in topics) or "none"
        raise ValueError(f"{path}: topic {wanted!r} is not a sensor_msgs/LaserScan topic; "
                         f"LaserScan topics: {listing}; all topics: {others}")
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        others = ", ".join(f"{t.name} ({t.msgtype})" for t in topics) or "none"
        raise ValueError(f"{path}: no sensor_msgs/LaserScan topic in the bag; topics: {others}")
    raise ValueError(f"{path}: several LaserScan topics, choose one with --topic: {listing}")


class _BagLog(LogSource):
    """What ROS 1 and ROS 2 bags share: topic choice, message conversion, info."""

    alternative_stamps = "bag record time"

    ros1 = False

    def __init__(self, path: str | Path, topic: str | None = None, strict: bool = False) -> None:
        super().__init__(path, topic, strict)
        self._notes: list[str] = []
        self._damage: list[str] = []  # what a record-by-record topic listing met
        self._topics = self._list_topics()
        try:
            self.topic = choose_scan_topic(self.path, self._topics, topic)
        except ValueError as exc:
            if not self._damage:
                raise
            raise ValueError(f"{exc}; the storage is damaged: {self._damage[0]}") from None

    def _list_topics(self) -> list[TopicEntry]:
        raise NotImplementedError

    def _raw_messages(self) -> Iterator[tuple[int, bytes]]:
        """``(bag time ns, serialised message)`` of ``self.topic`` in bag order."""
        raise NotImplementedError

    def _deserialize(self, raw: bytes) -> Any:
        store = _typestore(self.ros1)
        if self.ros1:
            return store.deserialize_ros1(raw, LASERSCAN)
        return store.deserialize_cdr(raw, LASERSCAN)

    def topics(self) -> list[dict[str, Any]]:
        return [{"name": t.name, "type": t.msgtype, "count": t.count} for t in self._topics]

    def _format_notes(self) -> list[str]:
        return list(self._notes)

    def _records(self) -> Iterator[tuple[LaserScan, str, Pose | None]]:
        convert = _ScanConverter(self)
        for index, (time_ns, raw) in enumerate(self._raw_messages(), start=1):
            where = f"message {index} on {self.topic}"
            try:
                msg = self._deserialize(raw)
            except Exception as exc:  # any decoding failure is a bad record
                self._skip(MALFORMED, where, f"cannot deserialise: {exc!r}")
                continue
            scan = convert(msg, time_ns, where)
            if scan is not None:
                self._alternative_stamp(time_ns * 1e-9)
                yield scan, where, None


# -- ROS 1 ----------------------------------------------------------------------------------------

OP_MSG_DATA = 0x02
OP_BAG_HEADER = 0x03
OP_INDEX_DATA = 0x04
OP_CHUNK = 0x05
OP_CHUNK_INFO = 0x06
OP_CONNECTION = 0x07
_OPS = frozenset({OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO,
                  OP_CONNECTION})
_U32 = struct.Struct("<I")
_MAGIC = b"#ROSBAG V2.0\n"
# A record header longer than this is taken for corruption (real ones are a few hundred bytes).
_MAX_HEADER_BYTES = 1 << 16
# The smallest message-data record: lengths, op, conn and time fields.
_MIN_MESSAGE_BYTES = 46


class BagFormatError(ValueError):
    """A ROS 1 bag record that cannot be parsed."""


def parse_record_header(blob: bytes) -> dict[str, bytes]:
    """``name=value`` fields of a ROS 1 bag record header (each preceded by its uint32 length)."""
    fields: dict[str, bytes] = {}
    pos = 0
    while pos < len(blob):
        if pos + 4 > len(blob):
            raise BagFormatError("header field length cut short")
        (size,) = _U32.unpack_from(blob, pos)
        pos += 4
        if pos + size > len(blob):
            raise BagFormatError(f"header field of {size} bytes overruns its header")
        name, sep, value = bytes(blob[pos : pos + size]).partition(b"=")
        if not sep:
            raise BagFormatError("header field without '='")
        fields[name.decode("latin-1")] = value
        pos += size
    return fields


def _field_u32(header: dict[str, bytes], name: str) -> int:
    value = header.get(name)
    if value is None or len(value) != 4:
        raise BagFormatError(f"record header without a 4-byte {name!r} field")
    return int(_U32.unpack(value)[0])


def _op(header: dict[str, bytes]) -> int:
    op = header.get("op", b"")
    if len(op) != 1 or op[0] not in _OPS:
        raise BagFormatError(f"record header with an unknown op {op!r}")
    return op[0]


def _decompress(name: str, data: bytes) -> tuple[bytes, int]:
    """A chunk's records and the bytes after its compressed stream (a declared chunk length
    that is too long shows as such trailing bytes)."""
    if name == "none":
        return bytes(data), 0
    if name == "bz2":
        decompressor: Any = bz2.BZ2Decompressor()
    elif name == "lz4":
        from lz4.frame import LZ4FrameDecompressor  # rosbags depends on lz4

        decompressor = LZ4FrameDecompressor()
    else:
        raise BagFormatError(f"unsupported chunk compression {name!r}")
    inner = decompressor.decompress(data)
    if not decompressor.eof:
        raise BagFormatError("compressed data ended before its end-of-stream marker")
    return inner, len(decompressor.unused_data or b"")


@dataclass
class _Bag1Connection:
    id: int
    topic: str
    msgtype: str


@dataclass
class _Record:
    op: int
    header: dict[str, bytes]
    start: int  # offset of the data
    size: int  # declared data length (may run past the end of a cut file)


class Bag1RecordReader:
    """Reads a ROS 1 (v2.0) bag's records in file order, without trusting its index.

    Iterating :meth:`messages` yields ``(connection, time_ns, raw)`` for every message it can
    read. Damage never ends the walk silently: a record that cannot be parsed is noted in
    ``problems`` with its byte offset and the walk resumes at the next record that parses (or
    stops at a cut end), and messages known to be lost (a damaged chunk whose index-data
    records say how many it held, messages whose connection record is missing) are counted
    per connection id in ``lost``.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.connections: dict[int, _Bag1Connection] = {}
        self.counts: Counter[int] = Counter()
        self.lost: Counter[int] = Counter()
        self.problems: list[str] = []
        self.repaired = 0  # index-data records whose declared length was wrong
        self._chunk_offset = -1  # the chunk being read, or the last one read
        self._in_chunk = False
        # (chunk offset, connection) -> messages the index says it holds / that were decoded /
        # whose connection is unknown (the offset of a top-level message stands for a chunk)
        self._expected: dict[tuple[int, int], int] = {}
        self._decoded: Counter[tuple[int, int]] = Counter()
        self._unknown: Counter[tuple[int, int]] = Counter()
        self._file: Any = b""
        self._escape: int | None = None  # where a chunk's records ran into top-level ones
        self._resume: int | None = None  # where the top-level walk goes on after a bad chunk

    @property
    def truncated(self) -> str | None:
        """The first problem met (with its byte offset), or None."""
        return self.problems[0] if self.problems else None

    def messages(self) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        self.connections.clear()
        self.counts.clear()
        self.lost.clear()
        self.problems = []
        self.repaired = 0
        self._expected, self._decoded, self._unknown = {}, Counter(), Counter()
        self._chunk_offset = -1
        with self.path.open("rb") as fh:
            magic = fh.read(len(_MAGIC))
            if magic != _MAGIC:
                raise BagFormatError(f"{self.path}: not a ROS 1 v2.0 bag (magic {magic!r})")
            size = fh.seek(0, 2)
            if size == len(_MAGIC):
                return
            # mapped, not read: a long bag is paged in as its records are visited
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
                self._file = data
                try:
                    yield from self._walk(data, len(_MAGIC), base=0, top_level=True)
                finally:
                    self._file = b""
        self._count_lost()

    def _count_lost(self) -> None:
        """Messages the index (index-data records after each chunk, chunk-info records at the
        end) says a chunk holds but that were not decoded; messages of an unknown connection
        where the index says nothing."""
        starts = sorted({chunk for chunk, _ in self._expected})
        decoded: Counter[tuple[int, int]] = Counter()
        unknown: Counter[tuple[int, int]] = Counter()
        for source, target in ((self._decoded, decoded), (self._unknown, unknown)):
            for (offset, conn), n in source.items():
                k = bisect.bisect_right(starts, offset) - 1
                target[(starts[k] if k >= 0 else offset, conn)] += n
        for (chunk, conn), n in self._expected.items():
            self.lost[conn] += max(0, n - decoded[(chunk, conn)])
        for (chunk, conn), n in unknown.items():
            if (chunk, conn) not in self._expected:
                self.lost[conn] += n

    # -- record parsing ------------------------------------------------------------------------
    def _parse(self, data: Any, pos: int) -> _Record:
        """The record at ``pos``; raises BagFormatError when its header does not parse."""
        if pos + 4 > len(data):
            raise BagFormatError("record length cut short")
        (header_len,) = _U32.unpack_from(data, pos)
        if header_len > _MAX_HEADER_BYTES:
            raise BagFormatError(f"record header of {header_len} bytes")
        if pos + 8 + header_len > len(data):
            raise BagFormatError(f"record header of {header_len} bytes cut short")
        header = parse_record_header(data[pos + 4 : pos + 4 + header_len])
        op = _op(header)
        (data_len,) = _U32.unpack_from(data, pos + 4 + header_len)
        start = pos + 8 + header_len
        if op == OP_INDEX_DATA:
            data_len = self._checked_index_length(header, data_len)
        return _Record(op, header, start, data_len)

    def _checked_index_length(self, header: dict[str, bytes], declared: int) -> int:
        """An index-data record's data length is fixed by its entry count.

        Some writers stored a wrong length in index-data records (``laser_scan_matcher_demo.bag``
        declares 20 bytes per entry; version 1 entries are 12): trusting it would land in the
        middle of the next chunk.
        """
        if header.get("ver") != _U32.pack(1):
            return declared
        actual = _field_u32(header, "count") * 12
        if actual != declared:
            self.repaired += 1
        return actual

    def _resync(self, data: Any, pos: int) -> int | None:
        """The offset of the next record that parses, from ``pos`` on (None if none): a
        record starts with its header length, then a header field of 4 to 64 bytes."""
        end = len(data)
        while pos + 8 <= end:
            (header_len,) = _U32.unpack_from(data, pos)
            if 8 <= header_len <= _MAX_HEADER_BYTES and pos + 8 + header_len <= end:
                (first,) = _U32.unpack_from(data, pos + 4)
                if 3 <= first <= min(header_len - 4, 64):
                    try:
                        record = self._parse(data, pos)
                    except BagFormatError:
                        record = None
                    if record is not None and record.start + record.size <= end:
                        return pos
            pos += 1
        return None

    def _walk(
        self, data: Any, pos: int, base: int, top_level: bool
    ) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        """Records of ``data`` from ``pos``; ``base`` is the file offset of ``data`` (a
        chunk's decompressed records are located by the chunk's offset)."""
        where = "byte" if top_level else f"chunk at byte {base}, record at"
        while pos < len(data):
            try:
                record = self._parse(data, pos)
            except BagFormatError as exc:
                resume = self._resync(data, pos + 1)
                tail = f"; resumed at {resume}" if resume is not None else ""
                self._problem(f"{where} {pos + (base if top_level else 0)}: {exc}{tail}")
                if resume is None:
                    return
                pos = resume
                continue
            end = record.start + record.size
            if end > len(data):
                self._problem(f"{where} {pos}: record data cut short "
                              f"({len(data) - record.start} of {record.size} bytes)")
                if record.op == OP_CHUNK and top_level:
                    yield from self._chunk(record, data[record.start :], pos, cut=True)
                return
            if not top_level and record.op not in (OP_CONNECTION, OP_MSG_DATA):
                # a chunk holds only connections and messages: its length was wrong and this
                # is the next top-level record; the caller resumes the walk there
                self._problem(f"{where} {pos}: a chunk declares a wrong length")
                self._escape = pos
                return
            if not top_level:
                yield from self._dispatch(record, data[record.start : end], pos, top_level)
                pos = end
                continue
            self._resume = None
            yield from self._dispatch(record, data[record.start : end], pos, top_level)
            pos = end if self._resume is None else self._resume

    def _problem(self, text: str) -> None:
        self.problems.append(text)

    def _dispatch(
        self, record: _Record, data: bytes, offset: int, top_level: bool
    ) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        try:
            if record.op == OP_CONNECTION:
                self._add_connection(record.header, data)
            elif record.op == OP_MSG_DATA:
                yield from self._message(record.header, data, offset)
            elif record.op == OP_CHUNK and top_level:
                yield from self._chunk(record, data, offset)
            elif record.op == OP_INDEX_DATA and top_level:
                self._index_data(record.header)
            elif record.op == OP_CHUNK_INFO and top_level:
                self._chunk_info(record.header, data)
        except BagFormatError as exc:
            self._problem(f"byte {offset}: {exc}")

    def _add_connection(self, header: dict[str, bytes], data: bytes) -> None:
        conn = _field_u32(header, "conn")
        if conn in self.connections:
            return
        fields = parse_record_header(data)
        topic = header.get("topic", fields.get("topic", b"")).decode("latin-1")
        msgtype = normalize_msgtype(fields.get("type", b"").decode("latin-1"))
        self.connections[conn] = _Bag1Connection(conn, topic, msgtype)

    def _message(
        self, header: dict[str, bytes], data: bytes, offset: int
    ) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        conn_id = _field_u32(header, "conn")
        stamp = header.get("time", b"")
        if len(stamp) != 8:
            raise BagFormatError("message record without an 8-byte time")
        where = (self._chunk_offset if self._in_chunk else offset, conn_id)
        conn = self.connections.get(conn_id)
        if conn is None:  # its connection record was lost: nothing can decode it
            self._unknown[where] += 1
            return
        self._decoded[where] += 1
        sec, nsec = struct.unpack("<II", stamp)
        self.counts[conn.id] += 1
        yield conn, sec * 1_000_000_000 + nsec, data

    def _chunk(
        self, record: _Record, data: bytes, offset: int, cut: bool = False
    ) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        self._chunk_offset = offset
        compression = record.header.get("compression", b"none").decode("latin-1")
        if cut and compression != "none":
            return  # a cut compressed chunk cannot be decompressed
        try:
            inner, extra = _decompress(compression, data)
        except Exception as exc:  # bz2/lz4 raise various types on bad data
            # its length may be what is wrong: go on at the next record after its header
            self._resume = self._resync(self._file, record.start)
            tail = f"; resumed at byte {self._resume}" if self._resume is not None else ""
            self._problem(f"chunk at byte {offset} cannot be decompressed: {exc}{tail}")
            if self._resume is None:
                self._resume = len(self._file)
            return
        if extra and not cut:
            self._resume = record.start + record.size - extra
            self._problem(f"chunk at byte {offset} declares {extra} bytes more than its "
                          f"compressed data; resumed at byte {self._resume}")
        problems = len(self.problems)
        self._escape = None
        self._in_chunk = True
        try:
            yield from self._walk(inner, 0, base=offset, top_level=False)
        finally:
            self._in_chunk = False
        if self._escape is not None and not cut:
            self._resume = record.start + self._escape
        if cut:  # the record cut inside the chunk is the cut already noted
            del self.problems[problems:]

    def _index_data(self, header: dict[str, bytes]) -> None:
        """An index-data record follows its chunk and says how many messages it holds."""
        if self._chunk_offset >= 0:
            conn = _field_u32(header, "conn")
            self._expect(self._chunk_offset, conn, _field_u32(header, "count"))

    def _chunk_info(self, header: dict[str, bytes], data: bytes) -> None:
        """A chunk-info record (end of the bag): the messages per connection of one chunk."""
        chunk_pos = header.get("chunk_pos", b"")
        if len(chunk_pos) != 8 or len(data) % 8:
            raise BagFormatError("chunk-info record with a bad chunk_pos or length")
        (chunk,) = struct.unpack("<Q", chunk_pos)
        for conn, count in struct.iter_unpack("<II", data):
            self._expect(chunk, conn, count)

    def _expect(self, chunk: int, conn: int, count: int) -> None:
        """Messages of ``conn`` the index gives ``chunk``; where two index records disagree
        (one is damaged) the smaller count, and never more than the file could hold."""
        count = min(count, len(self._file) // _MIN_MESSAGE_BYTES)
        self._expected[(chunk, conn)] = min(count, self._expected.get((chunk, conn), count))


class Rosbag1Log(_BagLog):
    """A ROS 1 bag: topics from ``rosbags``' index (or, if it is rejected, from a walk over the
    records), messages always from :class:`Bag1RecordReader`, which survives damage."""

    format = "rosbag1"
    ros1 = True

    def _list_topics(self) -> list[TopicEntry]:
        from rosbags.rosbag1 import Reader

        try:
            with Reader(self.path) as reader:
                counts: Counter[tuple[str, str]] = Counter()
                for c in reader.connections:
                    counts[(c.topic, c.msgtype)] += c.msgcount
        except Exception as exc:  # rosbags raises assertions as well as errors
            reason = str(exc) or f"{type(exc).__name__} in its index parser"
            self._notes.append(
                f"rosbags rejected the bag's index ({reason}); read its records sequentially"
            )
            return self._scan_records()
        return [TopicEntry(t, m, n) for (t, m), n in counts.items()]

    def _scan_records(self) -> list[TopicEntry]:
        reader = Bag1RecordReader(self.path)
        try:
            for _ in reader.messages():
                pass
        except BagFormatError as exc:
            raise ValueError(str(exc)) from None
        if reader.repaired:
            self._notes.append(
                f"{reader.repaired} index-data record(s) declared a wrong length; "
                "used 12 bytes per entry as the format specifies"
            )
        counts: Counter[tuple[str, str]] = Counter()
        for c in reader.connections.values():
            counts[(c.topic, c.msgtype)] += reader.counts[c.id] + reader.lost[c.id]
        return [TopicEntry(t, m, n) for (t, m), n in counts.items()]

    def _raw_messages(self) -> Iterator[tuple[int, bytes]]:
        reader = Bag1RecordReader(self.path)
        try:
            for conn, time_ns, raw in reader.messages():
                if conn.topic == self.topic and conn.msgtype == LASERSCAN:
                    yield time_ns, raw
        except BagFormatError as exc:
            raise ValueError(str(exc)) from None
        for problem in reader.problems:
            self._skip(TRUNCATED, problem)
        scan_ids = {c.id for c in reader.connections.values()
                    if c.topic == self.topic and c.msgtype == LASERSCAN}
        unknown = {i for i in reader.lost if i not in reader.connections}
        for conn_id in sorted(scan_ids | (unknown if len(scan_ids) else set())):
            if reader.lost[conn_id]:
                self._skip(DAMAGED, f"{reader.lost[conn_id]} message(s) of connection "
                           f"{conn_id} in damaged parts of the bag", count=reader.lost[conn_id])


# -- ROS 2 ----------------------------------------------------------------------------------------

class McapRecordReader:
    """Reads an MCAP file's records in file order, without its summary section.

    Used when ``rosbags`` cannot open the file (a truncated file has no footer). Iterating
    :meth:`messages` yields ``(topic, msgtype, log_time_ns, raw)``; ``truncated`` then says
    where the file stopped making sense (or None).
    """

    MAGIC = b"\x89MCAP0\r\n"
    _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_DATA_END = 0x03, 0x04, 0x05, 0x06, 0x0F

    def __init__(self, path: Path) -> None:
        self.path = path
        self.truncated: str | None = None
        self._schemas: dict[int, str] = {}
        self._channels: dict[int, tuple[str, str]] = {}

    def messages(self) -> Iterator[tuple[str, str, int, bytes]]:
        self.truncated = None
        with self.path.open("rb") as fh:
            if fh.read(len(self.MAGIC)) != self.MAGIC:
                raise BagFormatError("not an MCAP file (bad magic)")
            # mapped, not read: a long bag is paged in as its records are visited
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
                yield from self._records(data, len(self.MAGIC), top_level=True)

    def _records(
        self, data: bytes | mmap.mmap, pos: int, top_level: bool
    ) -> Iterator[tuple[str, str, int, bytes]]:
        while pos < len(data):
            if pos + 9 > len(data):
                self.truncated = f"byte {pos}: record opcode/length cut short"
                return
            op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
            body = data[pos + 9 : pos + 9 + length]
            if len(body) < length:
                if op == self._OP_CHUNK:  # an uncompressed chunk's complete records are usable
                    yield from self._chunk(body, pos, partial=True)
                self.truncated = f"byte {pos}: record of {length} bytes cut short at {len(body)}"
                return
            if op == self._OP_DATA_END and top_level:
                return
            try:
                yield from self._dispatch(op, body, pos)
            except (struct.error, UnicodeDecodeError, IndexError) as exc:
                self.truncated = f"byte {pos}: unreadable record ({exc})"
                return
            pos += 9 + length

    def _dispatch(self, op: int, body: bytes, pos: int) -> Iterator[tuple[str, str, int, bytes]]:
        if op == self._OP_SCHEMA:
            (schema_id,) = struct.unpack_from("<H", body, 0)
            name, _ = _mcap_string(body, 2)
            self._schemas[schema_id] = name
        elif op == self._OP_CHANNEL:
            channel_id, schema_id = struct.unpack_from("<HH", body, 0)
            topic, _ = _mcap_string(body, 4)
            self._channels[channel_id] = (topic, self._schemas.get(schema_id, ""))
        elif op == self._OP_MESSAGE:
            channel_id, _seq, log_time = struct.unpack_from("<HIQ", body, 0)
            if channel_id in self._channels:
                topic, msgtype = self._channels[channel_id]
                yield topic, msgtype, log_time, body[22:]
        elif op == self._OP_CHUNK:
            yield from self._chunk(body, pos)

    def _chunk(
        self, body: bytes, pos: int, partial: bool = False
    ) -> Iterator[tuple[str, str, int, bytes]]:
        uncompressed_size = struct.unpack_from("<Q", body, 16)[0]
        compression, at = _mcap_string(body, 28)
        (size,) = struct.unpack_from("<Q", body, at)
        records = body[at + 8 : at + 8 + size]
        if partial:
            if not compression:
                yield from self._records(records, 0, top_level=False)
            return
        try:
            if compression == "zstd":
                try:
                    from compression import zstd  # type: ignore[import-not-found]
                except ImportError:
                    from backports import zstd  # type: ignore[no-redef]  # rosbags' dependency
                records = zstd.decompress(records)
            elif compression == "lz4":
                from lz4.frame import decompress

                records = decompress(records)
            elif compression:
                raise BagFormatError(f"unsupported chunk compression {compression!r}")
        except Exception as exc:  # decompressors raise their own error types on bad data
            self.truncated = f"chunk at byte {pos} cannot be decompressed: {exc}"
            return
        if len(records) != uncompressed_size:
            self.truncated = f"chunk at byte {pos} has {len(records)} of {uncompressed_size} bytes"
            return
        yield from self._records(records, 0, top_level=False)


def _mcap_string(body: bytes, pos: int) -> tuple[str, int]:
    (length,) = struct.unpack_from("<I", body, pos)
    end = pos + 4 + length
    if end > len(body):
        raise IndexError("string overruns its record")
    return body[pos + 4 : end].decode("utf-8"), end


def _sqlite_size_mismatch(path: Path) -> str | None:
    """Why an SQLite file is shorter than its header says (it was cut), or None."""
    with path.open("rb") as fh:
        head = fh.read(100)
        size = fh.seek(0, 2)
    if len(head) < 100:
        return f"the file is {size} bytes, shorter than an SQLite header"
    page = struct.unpack_from(">H", head, 16)[0]
    page = 65536 if page == 1 else page
    pages, changes, valid_for = (struct.unpack_from(">I", head, k)[0] for k in (28, 24, 92))
    if changes == valid_for and pages and size < pages * page:
        return f"the file is {size} bytes, its header says {pages} pages of {page}"
    return None


class Sqlite3RecordReader:
    """Reads the ``messages`` table of a ROS 2 ``.db3`` row by row, for damaged files.

    Iterating :meth:`messages` yields ``(topic, msgtype, time_ns, raw)`` in row order. SQLite
    is asked first; when it fails (a truncated file, a damaged page) the rows not read yet are
    taken from the file's pages (:mod:`bioslam.io.sqlite_pages`), ``truncated`` says where and
    why, and ``lost`` counts rows known to be missing (gaps in the row ids, rows of a topic
    that cannot be named) per topic name ("" when unknown).
    """

    def __init__(self, path: Path, topics: dict[int, tuple[str, str]] | None = None) -> None:
        self.path = path
        self.truncated: str | None = None
        self.lost: Counter[str] = Counter()
        self.notes: list[str] = []
        self._known_topics = topics or {}

    def messages(self) -> Iterator[tuple[str, str, int, bytes]]:
        self.truncated = None
        self.lost = Counter()
        self.notes = []
        state: dict[str, Any] = {"last": 0, "error": None, "topics": {}}
        yield from self._by_sqlite(state)
        if state["error"] is None:
            state["error"] = _sqlite_size_mismatch(self.path)
        if state["error"] is not None:
            yield from self._by_pages(state["last"], state["error"], state["topics"])

    def _by_sqlite(self, state: dict[str, Any]) -> Iterator[tuple[str, str, int, bytes]]:
        import sqlite3

        try:
            db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
        except sqlite3.Error as exc:
            state["error"] = exc
            return
        try:
            state["topics"] = {row[0]: (row[1], row[2]) for row in
                               db.execute("SELECT id, name, type FROM topics")}
            rows = db.execute("SELECT id, topic_id, timestamp, data FROM messages ORDER BY id")
            for row_id, topic_id, stamp, raw in rows:
                if row_id != state["last"] + 1:
                    self.lost[""] += max(row_id - state["last"] - 1, 0)
                state["last"] = row_id
                name, msgtype = state["topics"].get(topic_id, ("", ""))
                if not name:
                    self.lost[""] += 1
                    continue
                yield name, msgtype, int(stamp), bytes(raw)
        except sqlite3.Error as exc:
            state["error"] = exc
        finally:
            db.close()

    def _by_pages(
        self, after: int, error: Exception, topics: dict[int, tuple[str, str]]
    ) -> Iterator[tuple[str, str, int, bytes]]:
        from bioslam.io.sqlite_pages import iter_rows, leaf_rows

        try:
            scan = leaf_rows(self.path.read_bytes())
        except ValueError as exc:
            raise BagFormatError(f"cannot open the database: {error}; {exc}") from None
        none = type(None)
        topics = topics or {rowid: (v[1], v[2]) for rowid, v in
                            iter_rows(scan, (none, str, str, str))} or self._known_topics
        rows = [(rowid, v) for rowid, v in iter_rows(scan, (none, int, int, bytes))
                if rowid > after]
        if not topics and rows:
            topics = self._guess_topics(rows)
        last = after
        for rowid, (_, topic_id, stamp, raw) in rows:
            self.lost[""] += rowid - last - 1  # rows in pages that could not be read
            last = rowid
            if topic_id not in topics:
                self.lost[""] += 1
                continue
            name, msgtype = topics[topic_id]
            yield name, msgtype, stamp, raw
        where = f"; first unreadable cell: {scan.first_bad}" if scan.first_bad else ""
        self.truncated = (f"SQLite stopped after message row {after} ({error}); "
                          f"{len(rows)} later rows read from the file's pages, up to row "
                          f"{last}{where}")

    def _guess_topics(self, rows: list[tuple[int, list[Any]]]) -> dict[int, tuple[str, str]]:
        """Without a topics table, name each topic whose first message decodes as a
        LaserScan ``topic <id>`` (said in ``notes``)."""
        first: dict[int, bytes] = {}
        for _, values in rows:
            first.setdefault(values[1], values[3])
        found = {}
        for topic_id, raw in sorted(first.items()):
            try:
                msg = _typestore(False).deserialize_cdr(raw, LASERSCAN)
                ok = len(msg.ranges) > 0 and float(msg.angle_increment) != 0.0
            except Exception:  # not a LaserScan
                ok = False
            if ok:
                found[topic_id] = (f"topic {topic_id}", LASERSCAN)
                self.notes.append(f"{self.path.name}: topic names lost with the topics table; "
                                  f"topic id {topic_id} holds LaserScans, read as "
                                  f"'topic {topic_id}'")
        return found


class Rosbag2Log(_BagLog):
    """A ROS 2 bag: a directory with ``metadata.yaml``, or a single ``.db3``/``.mcap`` file.

    When ``rosbags`` cannot open it (a truncated or damaged storage file, a missing
    ``metadata.yaml``), its storage files are read record by record instead and whatever is
    readable is kept.
    """

    format = "rosbag2"

    def _open_reader(self) -> Any:
        from rosbags.rosbag2 import Reader

        reader = Reader(self.path)
        reader.open()
        return reader

    def _list_topics(self) -> list[TopicEntry]:
        self._expected: dict[str, int] = {}
        try:
            reader = self._open_reader()
        except Exception as exc:  # sqlite/mcap/yaml errors alike
            self._notes.append(f"rosbags could not open the bag ({exc}); "
                               "read its storage files record by record")
            return self._salvage_topics()
        try:
            counts: Counter[tuple[str, str]] = Counter()
            for c in reader.connections:
                counts[(c.topic, c.msgtype)] += c.msgcount
        finally:
            reader.close()
        for (topic, _), n in counts.items():
            self._expected[topic] = self._expected.get(topic, 0) + n
        return [TopicEntry(t, m, n) for (t, m), n in counts.items()]

    def _storage_readers(self) -> list[McapRecordReader | Sqlite3RecordReader]:
        files = sorted(self.path.iterdir()) if self.path.is_dir() else [self.path]
        readers: list[McapRecordReader | Sqlite3RecordReader] = []
        for f in files:
            if f.suffix == ".mcap":
                readers.append(McapRecordReader(f))
            elif f.suffix == ".db3":
                readers.append(Sqlite3RecordReader(f))
        if not readers:
            raise ValueError(f"{self.path}: no .mcap or .db3 storage file in the ROS 2 bag")
        return readers

    def _salvaged(self, lost: Counter[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
        """Messages of every storage file in turn, each read record by record: a damaged
        file is reported (with where) and the next one still read."""
        for reader in self._storage_readers():
            try:
                for topic, msgtype, stamp, raw in reader.messages():
                    yield topic, normalize_msgtype(msgtype), stamp, raw
            except BagFormatError as exc:
                raise ValueError(f"{reader.path}: {exc}") from None
            for note in getattr(reader, "notes", []):
                if note not in self._notes:
                    self._notes.append(note)
            if lost is not None:
                lost.update(getattr(reader, "lost", Counter()))
            if reader.truncated:
                self._skip(TRUNCATED, f"{reader.path.name}: {reader.truncated}")

    def _salvage_topics(self) -> list[TopicEntry]:
        counts: Counter[tuple[str, str]] = Counter()
        strict, self.strict = self.strict, False  # the damage is reported when reading
        try:
            for topic, msgtype, _, _ in self._salvaged():
                counts[(topic, msgtype)] += 1
        finally:
            self.strict = strict
            self._damage = list(self.skip_examples.values())
            self._skipped.clear()
            self.skip_examples.clear()
        return [TopicEntry(t, m, n) for (t, m), n in counts.items()]

    def _raw_messages(self) -> Iterator[tuple[int, bytes]]:
        """The scan topic's messages, always read by the record readers (which survive
        damage); scans the bag's metadata or the storage says were lost are counted."""
        lost: Counter[str] = Counter()
        delivered = 0
        for topic, msgtype, stamp, raw in self._salvaged(lost):
            if topic == self.topic and msgtype == LASERSCAN:
                delivered += 1
                yield stamp, raw
        expected = self._expected.get(self.topic or "")
        missing = expected - delivered if expected is not None else lost[self.topic or ""]
        missing = max(missing, lost[""] if expected is None else 0)
        if missing > 0:
            self._skip(DAMAGED, f"{missing} message(s) of {self.topic} missing from damaged "
                       "storage", count=missing)
