"""Fuzzing the log readers with mangled copies of small logs of every format.

Mutations (Hypothesis, derandomised so CI sees the same corpus every run, plus seeded sweeps):
truncation at any offset, flipped, deleted, duplicated and inserted bytes; deleted, duplicated
and swapped lines; every time-stamp defect; NaN/inf/negative ranges; wrong beam counts; empty
files. Properties, for every mutated file:

* reading raises nothing but ``ValueError``/``FileNotFoundError``, and those name the file;
* every scan record is yielded or counted: ``records_seen`` equals the scan records in the file
  (text logs), or all the bag's scans unless a corruption is reported with its byte offset;
* the stamps yielded increase strictly;
* the same file read twice gives the same scans, stamps and counts.

The corpus size is printed by ``test_corpus_size`` (run with ``-s``).
"""

from __future__ import annotations

import hashlib
import re
import shutil
import sqlite3
import struct
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from _log_fixtures import SCANS, fixture, storage_file
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bioslam.io.defects import (
    BREEZYSLAM_DEFECTS,
    CARMEN_DEFECTS,
    breezyslam_with_defect,
    carmen_with_defect,
)
from bioslam.io.logs import TRUNCATED, open_log

CORPUS: Counter[str] = Counter()


def _settings(examples: int) -> settings:
    return settings(max_examples=examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# -- reading a mutated file and checking the properties ------------------------------------------

def _digest(path: Path, fmt: str | None) -> tuple[str, object] | None:
    """Read ``path`` whole; None when it is refused with a clear error (checked here)."""
    try:
        source = open_log(path, fmt=fmt)
        scans = list(source)
    except (ValueError, FileNotFoundError) as exc:
        assert str(path) in str(exc), f"the error does not name the file: {exc}"
        return None
    stamps = np.array([s.stamp for s in scans])
    assert np.all(np.isfinite(stamps)) and np.all(np.diff(stamps) > 0), source.time_source
    assert source.scans_read == len(scans) <= source.records_seen
    h = hashlib.sha256(stamps.tobytes())
    for scan in scans:
        h.update(scan.ranges.tobytes())
        h.update(scan.angles.tobytes())
    return h.hexdigest(), (source, dict(source.skipped))


def check(path: Path, kind: str, expected_records: int | None = None,
          fmt: str | None = None) -> object:
    """Read twice and check the properties; returns the source (None if refused)."""
    CORPUS[kind] += 1
    first = _digest(path, fmt)
    second = _digest(path, fmt)
    assert (first is None) == (second is None)
    if first is None:
        return None
    assert first[0] == second[0] and first[1][1] == second[1][1], "not deterministic"
    source = first[1][0]
    if expected_records is not None:
        assert source.records_seen == expected_records, (source.skipped, source.skip_examples)
    return source


def _scan_lines(path: Path, topic: str) -> int:
    """Scan records of a text log counted the way a reader meets them (universal newlines)."""
    with path.open(encoding="latin-1") as fh:
        if topic == "*":
            return sum(1 for line in fh if line.strip())
        return sum(1 for line in fh if line.split(None, 1)[:1] == [topic])


def _check_text(path: Path, kind: str, fmt: str | None = None) -> None:
    source = check(path, kind, fmt=fmt)
    if source is not None:
        topic = "*" if source.format == "breezyslam" else source.topic
        assert source.records_seen == _scan_lines(path, topic), source.skipped


# -- mutations ------------------------------------------------------------------------------------

BYTE_OPS = st.lists(
    st.tuples(
        st.sampled_from(["flip", "truncate", "delete", "duplicate", "insert"]),
        st.floats(0.0, 1.0),
        st.integers(1, 255),
        st.integers(1, 64),
    ),
    min_size=1, max_size=3,
)


def mutate_bytes(data: bytes, ops: list[tuple[str, float, int, int]]) -> bytes:
    buf = bytearray(data)
    for op, where, value, length in ops:
        pos = min(int(where * len(buf)), max(len(buf) - 1, 0))
        if not buf:
            break
        if op == "flip":
            buf[pos] ^= value
        elif op == "truncate":
            del buf[pos:]
        elif op == "delete":
            del buf[pos : pos + length]
        elif op == "duplicate":
            buf[pos:pos] = buf[pos : pos + length]
        else:
            buf[pos:pos] = bytes([value]) * length
    return bytes(buf)


BAD_NUMBERS = ["nan", "inf", "-inf", "-1", "0", "1e999", "-3600.5", "x", ""]
LINE_OPS = st.lists(
    st.tuples(
        st.sampled_from(["delete", "duplicate", "swap", "stamp", "range", "count", "blank"]),
        st.floats(0.0, 1.0),
        st.sampled_from(BAD_NUMBERS),
        st.floats(0.0, 1.0),
    ),
    min_size=1, max_size=4,
)


def _field_positions(fields: list[str], kind: str) -> dict[str, list[int]]:
    """Where the stamp, ranges and beam count are in a line of ``kind``."""
    if kind == "carmen" and fields and fields[0] == "FLASER" and len(fields) > 12:
        n = len(fields) - 11
        return {"stamp": [len(fields) - 3, len(fields) - 1], "range": list(range(2, 2 + n)),
                "count": [1]}
    if kind == "carmen":
        return {"stamp": [len(fields) - 3] if len(fields) > 3 else [], "range": [], "count": []}
    return {"stamp": [0], "range": list(range(25, len(fields))), "count": []}


def mutate_lines(text: str, ops: list, kind: str) -> str:
    lines = text.splitlines(keepends=True)
    for op, where, number, where2 in ops:
        if not lines:
            break
        i = min(int(where * len(lines)), len(lines) - 1)
        if op == "delete":
            del lines[i]
        elif op == "duplicate":
            lines.insert(i, lines[i])
        elif op == "swap" and i + 1 < len(lines):
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
        elif op == "blank":
            lines[i] = "\n"
        else:
            fields = lines[i].split()
            spots = _field_positions(fields, kind).get(op, [])
            if not spots:
                continue
            j = spots[min(int(where2 * len(spots)), len(spots) - 1)]
            if op == "stamp" and number in ("-3600.5",) and _is_float(fields[j]):
                number = repr(float(fields[j]) + 3600.0)  # one record an hour late
            fields[j] = number if op != "count" else str(int(where2 * 400) - 10)
            lines[i] = " ".join(fields) + "\n"
    return "".join(lines)


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _scratch() -> Path:
    return Path(tempfile.mkdtemp(prefix="bioslam-fuzz-"))


# -- text logs ------------------------------------------------------------------------------------

@pytest.mark.parametrize(("name", "kind"), [("robot.log", "carmen"), ("rover.dat", "breezyslam")])
@_settings(40)
@given(ops=LINE_OPS)
def test_text_logs_with_mangled_lines(name, kind, ops):
    text = fixture(name).read_text(encoding="latin-1")
    work = _scratch()
    try:
        path = work / name
        path.write_text(mutate_lines(text, ops, kind), encoding="latin-1")
        _check_text(path, f"{kind} lines")
    finally:
        shutil.rmtree(work)


@pytest.mark.parametrize(("name", "fmt"), [("robot.log", None), ("rover.dat", None),
                                           ("robot.log", "carmen"), ("rover.dat", "breezyslam")])
@_settings(25)
@given(ops=BYTE_OPS)
def test_text_logs_with_mangled_bytes(name, fmt, ops):
    work = _scratch()
    try:
        path = work / name
        path.write_bytes(mutate_bytes(fixture(name).read_bytes(), ops))
        _check_text(path, f"{name} bytes", fmt)
    finally:
        shutil.rmtree(work)


@pytest.mark.parametrize(
    ("name", "defect"),
    [("robot.log", d) for d in CARMEN_DEFECTS] + [("rover.dat", d) for d in BREEZYSLAM_DEFECTS],
)
def test_text_logs_with_each_stamp_defect_are_read_whole(tmp_path, name, defect):
    mutate = carmen_with_defect if name == "robot.log" else breezyslam_with_defect
    lines = fixture(name).read_text(encoding="latin-1").splitlines(keepends=True)
    path = tmp_path / name
    path.write_text("".join(mutate(lines, defect)), encoding="latin-1")
    source = check(path, "stamp defects", SCANS * (2 if defect == "concatenated" else 1))
    assert source.scans_read == source.records_seen  # nothing lost to the stamps


# -- ROS bags -------------------------------------------------------------------------------------

def _check_bag(path: Path, kind: str, fmt: str | None = None) -> None:
    source = check(path, kind, fmt=fmt)
    if source is None:
        return
    if source.records_seen != SCANS:
        # scans lost to a damaged part of the file: said, with where
        assert TRUNCATED in source.skipped, (source.records_seen, source.skipped)
        assert "byte" in source.skip_examples[TRUNCATED] or "row" in source.skip_examples[
            TRUNCATED], source.skip_examples


@pytest.mark.parametrize("compression", ["none", "bz2", "lz4"])
@_settings(40)
@given(ops=BYTE_OPS)
def test_ros1_bags_with_mangled_bytes(compression, ops):
    name = f"scans-{compression}.bag"
    work = _scratch()
    try:
        path = work / name
        path.write_bytes(mutate_bytes(fixture(name).read_bytes(), ops))
        _check_bag(path, f"ros1 {compression}")
    finally:
        shutil.rmtree(work)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@_settings(25)
@given(ops=BYTE_OPS)
def test_ros2_bags_with_mangled_bytes(storage, ops):
    bag = fixture(f"ros2-{storage}")
    work = _scratch()
    try:
        copy = work / bag.name
        shutil.copytree(bag, copy)
        store = storage_file(copy)
        store.write_bytes(mutate_bytes(store.read_bytes(), ops))
        _check_bag(copy, f"ros2 {storage}")
        _check_bag(store, f"ros2 {storage} file alone")
    finally:
        shutil.rmtree(work)


@pytest.mark.parametrize(
    "name", ["robot.log", "rover.dat", "scans-none.bag", "scans-bz2.bag", "scans-lz4.bag",
             "ros2-sqlite3", "ros2-mcap"],
)
def test_truncation_sweep(tmp_path, name):
    """Every log cut at 20 offsets spread over its length (and at 0)."""
    src = fixture(name)
    source_file = storage_file(src) if src.is_dir() else src
    data = source_file.read_bytes()
    for k, cut in enumerate(np.linspace(0, len(data) - 1, 21).astype(int)):
        path = tmp_path / f"{k}-{source_file.name}"
        path.write_bytes(data[:cut])
        if name.endswith((".log", ".dat")):
            _check_text(path, "truncations")
        else:
            _check_bag(path, "truncations")


def test_db3_truncated_at_90_percent_keeps_the_messages_before_the_damage(tmp_path):
    store = storage_file(fixture("ros2-sqlite3"))
    data = store.read_bytes()
    cut = tmp_path / "cut.db3"
    cut.write_bytes(data[: int(0.9 * len(data))])
    source = open_log(cut)
    scans = list(source)
    assert len(scans) >= SCANS // 2, source.skipped
    assert source.skipped.get(TRUNCATED) == 1 and cut.name in source.skip_examples[TRUNCATED]
    # what is recovered is exact: the first scans of the bag
    clean = list(open_log(fixture("ros2-sqlite3")))
    for got, want in zip(scans, clean, strict=False):
        assert got.stamp == want.stamp and got.ranges.tobytes() == want.ranges.tobytes()
    assert sqlite3.sqlite_version_info >= (3, 0)


def test_bag_under_a_text_name_is_read_by_content(tmp_path):
    path = tmp_path / "scans.log"
    shutil.copy(fixture("scans-lz4.bag"), path)
    source = check(path, "misnamed", SCANS)
    assert source.format == "rosbag1" and source.scans_read == SCANS


def test_empty_and_random_files_are_clear_errors(tmp_path):
    rng = np.random.default_rng(3)
    for k, name in enumerate(["a.log", "a.dat", "a.bag", "a.db3", "a.mcap", "a.clf.gz"]):
        for content in (b"", rng.bytes(3000)):
            path = tmp_path / f"{k}-{len(content)}-{name}"
            path.write_bytes(content)
            CORPUS["empty/random"] += 1
            with pytest.raises(ValueError) as info:
                list(open_log(path))
            assert str(path) in str(info.value)


def _bag_records(data: bytes) -> list[tuple[int, int, int, int]]:
    """``(offset, op, header length, data length)`` of a clean ROS 1 bag's top-level records."""
    from bioslam.io.rosbag import parse_record_header

    pos, out = data.index(b"\n") + 1, []
    while pos < len(data):
        (header_len,) = struct.unpack_from("<I", data, pos)
        header = parse_record_header(data[pos + 4 : pos + 4 + header_len])
        (data_len,) = struct.unpack_from("<I", data, pos + 4 + header_len)
        out.append((pos, header["op"][0], header_len, data_len))
        pos += 8 + header_len + data_len
    return out


def _damage(data: bytes, how: str) -> tuple[bytes, int]:
    """The bag with its second chunk damaged ``how``; and that chunk's offset."""
    pos, _, header_len, data_len = [r for r in _bag_records(data) if r[1] == 5][1]
    out = bytearray(data)
    if how == "flipped data":
        middle = pos + 8 + header_len + data_len // 2
        out[middle : middle + 8] = bytes(b ^ 0x5A for b in out[middle : middle + 8])
    elif how == "length too long":
        struct.pack_into("<I", out, pos + 4 + header_len, data_len + 500)
    elif how == "length too short":
        struct.pack_into("<I", out, pos + 4 + header_len, data_len - 100)
    else:  # a header field length that overruns the header
        out[pos + 4 : pos + 8] = b"\xff\xff\xff\x00"
    return bytes(out), pos


@pytest.mark.parametrize("compression", ["none", "bz2", "lz4"])
@pytest.mark.parametrize("how", ["flipped data", "length too long", "length too short",
                                 "bad header"])
def test_ros1_damaged_chunk_is_located_and_its_scans_counted(tmp_path, compression, how):
    data, chunk = _damage(fixture(f"scans-{compression}.bag").read_bytes(), how)
    path = tmp_path / "damaged.bag"
    path.write_bytes(data)
    source = open_log(path)
    scans = list(source)
    # every scan is read or counted: the bag's index says how many the damaged chunk held
    assert source.records_seen == SCANS, source.skipped
    assert len(scans) >= SCANS - 5  # one chunk of a few scans at most, the rest read
    assert TRUNCATED in source.skipped
    # located: the first problem is at the damaged chunk (or where its wrong length led)
    first = int(re.search(r"byte (\d+)", source.skip_examples[TRUNCATED]).group(1))
    assert chunk <= first < chunk + 3000, source.skip_examples
    with pytest.raises(ValueError, match=r"damaged\.bag: .*byte"):
        list(open_log(path, strict=True))


def test_corpus_size():
    """Runs last in this module: the number of mutated files read (printed with ``-s``)."""
    total = sum(CORPUS.values())
    print(f"\nreader fuzz corpus: {total} files: {dict(CORPUS)}")
    assert total == 0 or total >= 100
