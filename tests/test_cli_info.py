"""``bioslam info``: the table, the JSON summary line and clean errors."""

from __future__ import annotations

import json

import pytest
from _io_data import shared_log

from bioslam.cli import main


def _flaser(t: float, n: int = 181) -> str:
    return f"FLASER {n} " + " ".join(["2.5"] * n) + f" 0 0 0 0 0 0 {t} host {t}\n"


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["info", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_info_prints_table_then_json_summary(tmp_path, capsys):
    log = tmp_path / "lab.log"
    log.write_text(
        "".join(_flaser(10.0 + 0.2 * k) for k in range(6))
        + "FLASER 181 1 2 3\n"  # line 7: cut short
        + _flaser(10.5)  # line 8: stamped before the scan ahead of it: repaired, kept last
    )
    code, out, err = _run(capsys, str(log))
    # 7 of 8 scan records read: below the default 90 %, so the command fails unless told
    assert code == 1
    assert "only 7 of 8 scan records read" in err and "--accept-partial" in err
    assert "skipped 1 x wrong beam count (first: line 7" in err
    code, out, _ = _run(capsys, str(log), "--accept-partial")
    assert code == 0
    assert _run(capsys, str(log), "--min-read-share", "0.85")[0] == 0
    lines = out.strip().splitlines()
    summary = json.loads(lines[-1])
    assert summary["format"] == "carmen"
    assert summary["scans"] == 7
    assert summary["beams"] == 181
    assert summary["fov_deg"] == pytest.approx(180.0)
    assert summary["duration_s"] == pytest.approx(1.2)  # the last a period after the one before
    assert summary["skipped"] == {"wrong beam count": 1}
    assert summary["scan_records"] == 8 and summary["read_share"] == pytest.approx(7 / 8)
    table = "\n".join(lines[:-1])
    assert "Format:" in table and "carmen" in table
    assert "Scans:             7" in table
    assert "line 7: wrong beam count" in table
    assert "1 repaired" in table


def test_info_unknown_format_exits_2_listing_formats(tmp_path, capsys):
    path = tmp_path / "x.txt"
    path.write_text("nothing to see\n")
    code, out, err = _run(capsys, str(path))
    assert code == 2 and out == ""
    assert "unknown log format" in err and "breezyslam" in err and "rosbag2" in err


def test_info_strict_names_file_and_line(tmp_path, capsys):
    log = tmp_path / "bad.log"
    log.write_text(_flaser(1.0) + "FLASER 181 oops\n")
    code, _, err = _run(capsys, str(log), "--strict")
    assert code == 2
    assert "bad.log: line 2: wrong beam count" in err


def test_info_on_the_shared_bag(capsys):
    code, out, _ = _run(capsys, str(shared_log("laser_scan_matcher_demo.bag")))
    assert code == 0
    summary = json.loads(out.strip().splitlines()[-1])
    assert (summary["format"], summary["scans"], summary["beams"]) == ("rosbag1", 360, 681)
    assert summary["duration_s"] == pytest.approx(35.8, abs=0.1)
    assert "/scan | Type: sensor_msgs/msg/LaserScan | Count: 360 (read)" in out
