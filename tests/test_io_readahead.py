"""A log read ahead in a child process (``bioslam.io.readahead``) gives the run exactly what
reading it in the process gives: the same scans bit for bit, and at every scan the same
read-outs (skips with their first example, records met, notes, reference poses, the time
source), also when the run stops half-way or a strict read meets a bad record."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from _cli_logs import write_carmen
from _log_fixtures import carmen_text

from bioslam.io import logs
from bioslam.io.logs import open_log
from bioslam.io.readahead import ReadAhead

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="read-ahead needs fork")
SRC = Path(__file__).resolve().parents[1] / "src"


def adversarial_log(path: Path, scans: int = 300) -> Path:
    """A corrected CARMEN log with what the reader repairs or skips: a cut-short scan
    record, a repeated stamp, a stamp 50 s ahead, a malformed odometry record and a scan
    stored three records late (put back in order)."""
    lines = carmen_text(scans).splitlines(keepends=True)
    flaser = [i for i, line in enumerate(lines) if line.startswith("FLASER")]

    def stamp(i: int) -> float:
        return float(lines[i].split()[-3])

    def restamp(i: int, t: float) -> None:
        fields = lines[i].split()
        fields[-3] = fields[-1] = f"{t:.6f}"
        lines[i] = " ".join(fields) + "\n"

    lines[flaser[5]] = "FLASER 181 1.0 2.0\n"
    restamp(flaser[20], stamp(flaser[19]))
    restamp(flaser[130], stamp(flaser[130]) + 50.0)
    lines[flaser[133] - 1] = "ODOM 1 2\n"
    late, lines[flaser[210]] = lines[flaser[210]], ""
    lines[flaser[213]] += late
    path.write_text("".join(lines))
    return path


def read_outs(source) -> dict:
    reference = source.reference
    return {
        "scans_read": source.scans_read, "records_seen": source.records_seen,
        "complete": source.complete, "skipped": source.skipped,
        "skip_examples": source.skip_examples, "notes": source.notes(),
        "reference": None if reference is None else (reference.stamps.tolist(),
                                                     reference.poses.tolist()),
    }  # fmt: skip


def same_scan(a, b) -> None:
    assert a.stamp == b.stamp
    assert a.ranges.dtype == b.ranges.dtype and a.ranges.tobytes() == b.ranges.tobytes()
    assert a.angles.tobytes() == b.angles.tobytes()
    assert (a.range_min, a.range_max, a.time_increment) == (
        b.range_min, b.range_max, b.time_increment)


def test_same_scans_and_read_outs_at_every_scan(tmp_path):
    path = adversarial_log(tmp_path / "room-corrected.log")
    direct = open_log(path)
    with ReadAhead(open_log(path), batch=16) as ahead:
        count = 0
        for a, b in zip(ahead, direct, strict=True):
            same_scan(a, b)
            count += 1
            assert read_outs(ahead) == read_outs(direct), count
        assert read_outs(ahead) == read_outs(direct)
        assert ahead.time_source == direct.time_source
    # the log exercised what it was written for
    assert direct.complete and count == 299
    assert set(direct.skipped) == {"wrong beam count", "malformed odometry record"}
    assert "repaired" in direct.time_source  # the scans stamped early, too, kept in file order


def test_a_run_that_stops_half_way_reports_what_it_took(tmp_path):
    path = adversarial_log(tmp_path / "room-corrected.log")
    direct, ahead = open_log(path), ReadAhead(open_log(path), batch=64)
    pid = ahead.pid
    for a, b in zip(ahead, direct, strict=True):  # the child is a batch or more ahead
        same_scan(a, b)
        if a.stamp - direct.time_plan.stamps[0] > 12.0:
            break
    assert read_outs(ahead) == read_outs(direct)
    assert not ahead.complete and 100 < ahead.scans_read < 299
    ahead.close()
    with pytest.raises(ChildProcessError):  # stopped and reaped
        os.waitpid(pid, os.WNOHANG)


@pytest.mark.parametrize("replay", [True, False])
def test_a_strict_read_fails_at_the_same_scan_with_the_same_message(tmp_path, monkeypatch,
                                                                    replay):
    if not replay:  # as a log too long for the time plan's pass to keep: parsed twice
        monkeypatch.setattr(logs, "REPLAY_BUDGET_BYTES", 0)
    path = adversarial_log(tmp_path / "room-corrected.log")
    direct = open_log(path, strict=True)
    taken = []
    with pytest.raises(ValueError) as expected:
        for scan in direct:
            taken.append(scan.stamp)
    with ReadAhead(open_log(path, strict=True)) as ahead:
        got = []
        with pytest.raises(ValueError) as raised:
            for scan in ahead:
                got.append(scan.stamp)
    assert str(raised.value) == str(expected.value)
    assert str(raised.value) == (f"{path}: line 20: wrong beam count: FLASER declares 181 "
                                 "beams but the line has 4 fields (expected 192)")
    assert got == taken


def test_the_run_command_writes_the_same_either_way(tmp_path):
    log = write_carmen(tmp_path / "room.log", scans=80, bad={7, 30})
    outputs = {}
    modes = {"ahead": [], "in-process": ["--one-process"], "drawn-in-child": ["--draw-in-child"]}
    for mode, options in modes.items():
        out = tmp_path / mode
        cmd = [sys.executable, "-m", "bioslam.cli", "run", str(log), "--out", str(out),
               "--no-progress", *options]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=300,
                              env={**os.environ, "PYTHONPATH": str(SRC)})  # fmt: skip
        assert done.returncode == 0, done.stderr
        summary = json.loads(done.stdout.strip().splitlines()[-1])
        assert summary["skipped"] == {"wrong beam count": 2} and summary["scans"] == 78
        figures = sorted((out / "figures").glob("*.png"))
        assert len(figures) >= 3
        outputs[mode] = [(out / name).read_bytes() for name in
                         ("trajectory.tum", "odometry.tum", "cognitive_map.json", "map.pgm")]
        outputs[mode] += [(f.name, f.read_bytes()) for f in figures]
        assert "skipped 2 x wrong beam count (first: line 8" in done.stderr
    assert outputs["ahead"] == outputs["in-process"] == outputs["drawn-in-child"]
