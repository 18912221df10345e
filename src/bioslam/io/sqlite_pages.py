"""Rows of a damaged SQLite file read straight from its pages (SQLite file format, sec. 1.6, 2.1).

SQLite refuses a truncated or damaged database as soon as a query touches a bad page, and the
pages a ROS 2 ``.db3`` needs first (the topics table, interior b-tree pages) are often the ones
written last. The rows themselves sit in table leaf pages that stand alone: this module walks
every page, decodes every table-leaf cell it can (following overflow pages for long blobs) and
returns the records with their rowids. A cell that cannot be decoded is counted, never guessed.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

_LEAF_TABLE = 0x0D
_HEADER = b"SQLite format 3\x00"


@dataclass
class PageScan:
    """What :func:`leaf_rows` found: rows ``(rowid, values)`` and the cells it could not read."""

    rows: list[tuple[int, list[Any]]] = field(default_factory=list)
    bad_cells: int = 0
    first_bad: str | None = None

    def bad(self, where: str) -> None:
        self.bad_cells += 1
        if self.first_bad is None:
            self.first_bad = where


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    """SQLite's big-endian varint (1-9 bytes) at ``pos``: (value, next position)."""
    value = 0
    for i in range(8):
        if pos + i >= len(buf):
            raise IndexError("varint cut short")
        byte = buf[pos + i]
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, pos + i + 1
    if pos + 8 >= len(buf):
        raise IndexError("varint cut short")
    return (value << 8) | buf[pos + 8], pos + 9


_INT_SIZES = {1: 1, 2: 2, 3: 3, 4: 4, 5: 6, 6: 8}


def decode_record(payload: bytes) -> list[Any]:
    """The column values of a record (header of serial types, then the values)."""
    header_size, pos = _varint(payload, 0)
    types = []
    while pos < header_size:
        serial, pos = _varint(payload, pos)
        types.append(serial)
    values: list[Any] = []
    body = header_size
    for serial in types:
        if serial in _INT_SIZES:
            n = _INT_SIZES[serial]
            values.append(int.from_bytes(payload[body : body + n], "big", signed=True))
        elif serial == 7:
            values.append(struct.unpack(">d", payload[body : body + 8])[0])
            n = 8
        elif serial in (0, 8, 9):
            values.append(None if serial == 0 else serial - 8)
            n = 0
        elif serial >= 12:
            n = (serial - 12) // 2
            raw = bytes(payload[body : body + n])
            values.append(raw if serial % 2 == 0 else raw.decode("utf-8", "replace"))
        else:
            raise ValueError(f"reserved serial type {serial}")
        if body + n > len(payload):
            raise IndexError("record value overruns its payload")
        body += n
    return values


class _File:
    def __init__(self, data: bytes) -> None:
        if not data.startswith(_HEADER) or len(data) < 100:
            raise ValueError("not an SQLite database (bad header)")
        size = struct.unpack_from(">H", data, 16)[0]
        self.page_size = 65536 if size == 1 else size
        if self.page_size < 512 or self.page_size & (self.page_size - 1):
            raise ValueError(f"bad page size {self.page_size}")
        self.usable = self.page_size - data[20]
        self.data = data
        self.pages = len(data) // self.page_size

    def page(self, number: int) -> bytes:
        if not 1 <= number <= self.pages:
            raise IndexError(f"page {number} beyond the end of the file")
        start = (number - 1) * self.page_size
        return self.data[start : start + self.page_size]

    def payload(self, page: bytes, cell: int) -> tuple[int, bytes]:
        """(rowid, payload) of the table-leaf cell at offset ``cell`` of ``page``."""
        size, pos = _varint(page, cell)
        rowid, pos = _varint(page, pos)
        u = self.usable
        x = u - 35
        if size <= x:
            if pos + size > u:
                raise IndexError("cell overruns its page")
            return rowid, page[pos : pos + size]
        m = ((u - 12) * 32 // 255) - 23
        k = m + ((size - m) % (u - 4))
        local = k if k <= x else m
        parts = [page[pos : pos + local]]
        (overflow,) = struct.unpack_from(">I", page, pos + local)
        got = local
        seen = set()
        while got < size:
            if overflow in seen:
                raise ValueError("overflow pages loop")
            seen.add(overflow)
            chunk = self.page(overflow)
            take = min(u - 4, size - got)
            parts.append(chunk[4 : 4 + take])
            got += take
            (overflow,) = struct.unpack_from(">I", chunk, 0)
        return rowid, b"".join(parts)


def leaf_rows(data: bytes) -> PageScan:
    """Every row of every table-leaf page of the database image ``data`` (page order).

    Raises ``ValueError`` when ``data`` is not an SQLite file at all.
    """
    db = _File(data)
    scan = PageScan()
    for number in range(1, db.pages + 1):
        page = db.page(number)
        head = 100 if number == 1 else 0
        if page[head] != _LEAF_TABLE:
            continue
        (cells,) = struct.unpack_from(">H", page, head + 3)
        for k in range(cells):
            at = head + 8 + 2 * k
            where = f"page {number} (byte {(number - 1) * db.page_size}), cell {k}"
            try:
                (cell,) = struct.unpack_from(">H", page, at)
                rowid, payload = db.payload(page, cell)
                scan.rows.append((rowid, decode_record(payload)))
            except (IndexError, ValueError, struct.error):
                scan.bad(where)
    return scan


def iter_rows(scan: PageScan, shape: tuple[type, ...]) -> Iterator[tuple[int, list[Any]]]:
    """The rows whose values have the types ``shape`` (``type(None)`` for a rowid alias),
    each rowid once (the first copy found), in rowid order."""
    seen: set[int] = set()
    rows = []
    for rowid, values in scan.rows:
        if len(values) >= len(shape) and rowid not in seen and all(
            isinstance(v, t) for v, t in zip(values, shape, strict=False)
        ):
            seen.add(rowid)
            rows.append((rowid, values))
    rows.sort(key=lambda r: r[0])
    yield from rows
