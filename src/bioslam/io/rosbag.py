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

import bz2
import mmap
import struct
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from bioslam.io.logs import MALFORMED, TRUNCATED, WRONG_BEAM_COUNT, LogSource, Pose
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

    ros1 = False

    def __init__(self, path: str | Path, topic: str | None = None, strict: bool = False) -> None:
        super().__init__(path, topic, strict)
        self._notes: list[str] = []
        self._topics = self._list_topics()
        self.topic = choose_scan_topic(self.path, self._topics, topic)

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
                yield scan, where, None


# -- ROS 1 ----------------------------------------------------------------------------------------

OP_MSG_DATA = 0x02
OP_BAG_HEADER = 0x03
OP_INDEX_DATA = 0x04
OP_CHUNK = 0x05
OP_CONNECTION = 0x07
_U32 = struct.Struct("<I")


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
        name, sep, value = blob[pos : pos + size].partition(b"=")
        if not sep:
            raise BagFormatError("header field without '='")
        fields[name.decode("latin-1")] = value
        pos += size
    return fields


def _decompressor(name: str) -> Callable[[bytes], bytes]:
    if name == "none":
        return lambda data: data
    if name == "bz2":
        return bz2.decompress
    if name == "lz4":
        from lz4.frame import decompress  # rosbags depends on lz4

        return decompress  # type: ignore[no-any-return]
    raise BagFormatError(f"unsupported chunk compression {name!r}")


@dataclass
class _Bag1Connection:
    id: int
    topic: str
    msgtype: str


class Bag1RecordReader:
    """Reads a ROS 1 (v2.0) bag's records in file order, without its index.

    Iterating :meth:`messages` yields ``(connection, time_ns, raw)`` for every message; at the
    end ``truncated`` holds a description of where the file stopped making sense (or None).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.connections: dict[int, _Bag1Connection] = {}
        self.counts: Counter[int] = Counter()
        self.truncated: str | None = None
        self.repaired = 0  # index-data records whose declared length was wrong

    def messages(self) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        self.truncated = None
        self.repaired = 0
        with self.path.open("rb") as fh:
            magic = fh.readline()
            if not magic.startswith(b"#ROSBAG V2.0"):
                raise BagFormatError(f"{self.path}: not a ROS 1 v2.0 bag (magic {magic[:13]!r})")
            while True:
                offset = fh.tell()
                try:
                    record = self._read_record(fh)
                except BagFormatError as exc:
                    self.truncated = f"byte {offset}: {exc}"
                    return
                if record is None:
                    return
                header, data, complete = record
                yield from self._dispatch(header, data, offset)
                if not complete:
                    return

    def _read_record(self, fh: BinaryIO) -> tuple[dict[str, bytes], bytes, bool] | None:
        """The next record, or None at a clean end of file. A record whose data is cut short
        is returned with ``complete=False`` (an uncompressed chunk still holds messages)."""
        head = fh.read(4)
        if not head:
            return None
        if len(head) < 4:
            raise BagFormatError("record length cut short")
        (header_len,) = _U32.unpack(head)
        blob = fh.read(header_len)
        if len(blob) < header_len:
            raise BagFormatError(f"record header cut short ({len(blob)} of {header_len} bytes)")
        header = parse_record_header(blob)
        size_bytes = fh.read(4)
        if len(size_bytes) < 4:
            raise BagFormatError("record data length cut short")
        (data_len,) = _U32.unpack(size_bytes)
        data_len = self._checked_data_length(header, data_len)
        data = fh.read(data_len)
        if len(data) < data_len:
            self.truncated = f"record data cut short ({len(data)} of {data_len} bytes)"
            return header, data, False
        return header, data, True

    def _checked_data_length(self, header: dict[str, bytes], declared: int) -> int:
        """The data length of a record; an index-data record's is fixed by its entry count.

        Some writers stored a wrong length in index-data records (``laser_scan_matcher_demo.bag``
        declares 20 bytes per entry; version 1 entries are 12): trusting it would land in the
        middle of the next chunk.
        """
        if header.get("op", b"\xff")[0] != OP_INDEX_DATA or header.get("ver") != _U32.pack(1):
            return declared
        actual = _U32.unpack(header["count"])[0] * 12
        if actual != declared:
            self.repaired += 1
        return actual

    def _dispatch(
        self, header: dict[str, bytes], data: bytes, offset: int
    ) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        op = header.get("op", b"\xff")[0]
        if op == OP_CONNECTION:
            self._add_connection(header, data)
        elif op == OP_MSG_DATA:
            yield from self._message(header, data)
        elif op == OP_CHUNK:
            yield from self._chunk(header, data, offset)

    def _add_connection(self, header: dict[str, bytes], data: bytes) -> None:
        conn = _U32.unpack(header["conn"])[0]
        if conn in self.connections:
            return
        fields = parse_record_header(data)
        topic = header.get("topic", fields.get("topic", b"")).decode("latin-1")
        msgtype = normalize_msgtype(fields.get("type", b"").decode("latin-1"))
        self.connections[conn] = _Bag1Connection(conn, topic, msgtype)

    def _message(
        self, header: dict[str, bytes], data: bytes
    ) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        conn = self.connections.get(_U32.unpack(header["conn"])[0])
        if conn is None:
            return  # a message before its connection record: nothing can decode it
        sec, nsec = struct.unpack("<II", header["time"])
        self.counts[conn.id] += 1
        yield conn, sec * 1_000_000_000 + nsec, data

    def _chunk(
        self, header: dict[str, bytes], data: bytes, offset: int
    ) -> Iterator[tuple[_Bag1Connection, int, bytes]]:
        compression = header.get("compression", b"none").decode("latin-1")
        try:
            inner = _decompressor(compression)(data)
        except Exception as exc:  # bz2/lz4 raise various types on bad data
            self.truncated = f"chunk at byte {offset} cannot be decompressed: {exc}"
            return
        pos = 0
        while pos + 4 <= len(inner):
            (header_len,) = _U32.unpack_from(inner, pos)
            end_header = pos + 4 + header_len
            if end_header + 4 > len(inner):
                break
            rec_header = parse_record_header(inner[pos + 4 : end_header])
            (data_len,) = _U32.unpack_from(inner, end_header)
            start = end_header + 4
            if start + data_len > len(inner):
                break
            yield from self._dispatch(rec_header, inner[start : start + data_len], offset)
            pos = start + data_len


class Rosbag1Log(_BagLog):
    """A ROS 1 bag, through ``rosbags``' indexed reader or, if that fails, record by record."""

    format = "rosbag1"
    ros1 = True

    def _list_topics(self) -> list[TopicEntry]:
        from rosbags.rosbag1 import Reader

        self._indexed = True
        try:
            with Reader(self.path) as reader:
                counts: Counter[tuple[str, str]] = Counter()
                for c in reader.connections:
                    counts[(c.topic, c.msgtype)] += c.msgcount
        except Exception as exc:  # rosbags raises assertions as well as errors
            self._indexed = False
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
        conns = reader.connections.values()
        counts: Counter[tuple[str, str]] = Counter()
        for c in conns:
            counts[(c.topic, c.msgtype)] += reader.counts[c.id]
        return [TopicEntry(t, m, n) for (t, m), n in counts.items()]

    def _raw_messages(self) -> Iterator[tuple[int, bytes]]:
        if self._indexed:
            yield from self._indexed_messages()
            return
        reader = Bag1RecordReader(self.path)
        for conn, time_ns, raw in reader.messages():
            if conn.topic == self.topic and conn.msgtype == LASERSCAN:
                yield time_ns, raw
        if reader.truncated:
            self._skip(TRUNCATED, reader.truncated)

    def _indexed_messages(self) -> Iterator[tuple[int, bytes]]:
        from rosbags.rosbag1 import Reader

        with Reader(self.path) as reader:
            conns = [c for c in reader.connections if c.topic == self.topic]
            try:
                for _, time_ns, raw in reader.messages(connections=conns):
                    yield time_ns, raw
            except Exception as exc:  # damaged chunk data
                self._skip(TRUNCATED, "indexed read", str(exc) or type(exc).__name__)


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


class Sqlite3RecordReader:
    """Reads the ``messages`` table of a ROS 2 ``.db3`` row by row, for damaged files.

    Iterating :meth:`messages` yields ``(topic, msgtype, time_ns, raw)`` in insertion order;
    rows past a damaged page end the iteration and set ``truncated``.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.truncated: str | None = None

    def messages(self) -> Iterator[tuple[str, str, int, bytes]]:
        import sqlite3

        self.truncated = None
        try:
            db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
        except sqlite3.Error as exc:
            raise BagFormatError(f"cannot open the database: {exc}") from None
        try:
            try:
                topics = {row[0]: (row[1], row[2]) for row in
                          db.execute("SELECT id, name, type FROM topics")}
            except sqlite3.Error as exc:
                raise BagFormatError(f"cannot read the topics table: {exc}") from None
            rows = db.execute("SELECT id, topic_id, timestamp, data FROM messages ORDER BY id")
            last_id = 0
            try:
                for row_id, topic_id, stamp, raw in rows:
                    last_id = row_id
                    if topic_id in topics:
                        name, msgtype = topics[topic_id]
                        yield name, msgtype, int(stamp), bytes(raw)
            except sqlite3.Error as exc:
                self.truncated = f"after message row {last_id}: {exc}"
        finally:
            db.close()


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
        self._salvage = False
        try:
            reader = self._open_reader()
        except Exception as exc:  # sqlite/mcap/yaml errors alike
            self._salvage = True
            self._notes.append(f"rosbags could not open the bag ({exc}); "
                               "read its storage files record by record")
            return self._salvage_topics()
        try:
            counts: Counter[tuple[str, str]] = Counter()
            for c in reader.connections:
                counts[(c.topic, c.msgtype)] += c.msgcount
        finally:
            reader.close()
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

    def _salvaged(self) -> Iterator[tuple[str, str, int, bytes]]:
        for reader in self._storage_readers():
            try:
                for topic, msgtype, stamp, raw in reader.messages():
                    yield topic, normalize_msgtype(msgtype), stamp, raw
            except BagFormatError as exc:
                raise ValueError(f"{reader.path}: {exc}") from None
            if reader.truncated:
                self._skip(TRUNCATED, f"{reader.path.name}: {reader.truncated}")
                return

    def _salvage_topics(self) -> list[TopicEntry]:
        counts: Counter[tuple[str, str]] = Counter()
        strict, self.strict = self.strict, False  # the truncation is reported when reading
        try:
            for topic, msgtype, _, _ in self._salvaged():
                counts[(topic, msgtype)] += 1
        finally:
            self.strict = strict
            self._skipped.clear()
            self.skip_examples.clear()
        return [TopicEntry(t, m, n) for (t, m), n in counts.items()]

    def _raw_messages(self) -> Iterator[tuple[int, bytes]]:
        if self._salvage:
            for topic, msgtype, stamp, raw in self._salvaged():
                if topic == self.topic and msgtype == LASERSCAN:
                    yield stamp, raw
            return
        reader = self._open_reader()
        try:
            conns = [c for c in reader.connections if c.topic == self.topic]
            try:
                for _, time_ns, raw in reader.messages(connections=conns):
                    yield time_ns, raw
            except Exception as exc:  # a damaged file fails mid-way
                self._skip(TRUNCATED, "reading messages", str(exc) or type(exc).__name__)
        finally:
            reader.close()
