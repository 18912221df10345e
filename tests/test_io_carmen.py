"""CARMEN reader: message layouts, beam angles, reference/odometry, bad input, real logs."""

from __future__ import annotations

import gzip

import numpy as np
import pytest
from _io_data import shared_log

from bioslam.io.carmen import CarmenConfig, CarmenLog
from bioslam.io.logs import (
    EMPTY_SCAN,
    MALFORMED,
    NO_VALID_RETURNS,
    TRUNCATED,
    WRONG_BEAM_COUNT,
    open_log,
)


def flaser(ranges, t, pose=(1.0, 2.0, 0.5), odom=(0.0, 0.0, 0.0)) -> str:
    values = " ".join(f"{r:g}" for r in ranges)
    p = " ".join(f"{v:g}" for v in (*pose, *odom))
    return f"FLASER {len(ranges)} {values} {p} {t:.6f} host {t:.6f}\n"


def robotlaser(ranges, t, start=-1.0, res=0.01, max_range=20.0, laser=(3.0, 4.0, 0.1)) -> str:
    values = " ".join(f"{r:g}" for r in ranges)
    tail = f"{laser[0]} {laser[1]} {laser[2]} 0 0 0 0 0 0.5 0.5 0"
    return (f"ROBOTLASER1 0 {start} {res * (len(ranges) - 1)} {res} {max_range} 0.01 0 "
            f"{len(ranges)} {values} 2 7 7 {tail} {t:.6f} host {t:.6f}\n")


def rawlaser(ranges, t, start=-0.5, res=0.5, max_range=8.0) -> str:
    values = " ".join(f"{r:g}" for r in ranges)
    return (f"RAWLASER1 0 {start} {res * (len(ranges) - 1)} {res} {max_range} 0.01 0 "
            f"{len(ranges)} {values} 0 {t:.6f} host {t:.6f}\n")


def odom(x, y, th, t) -> str:
    return f"ODOM {x} {y} {th} 0 0 0 {t:.6f} host {t:.6f}\n"


def write(path, lines, gz=False):
    text = "# CARMEN log\nPARAM robot_width 0.5 0 host 0\n" + "".join(lines)
    if gz:
        with gzip.open(path, "wt") as fh:
            fh.write(text)
    else:
        path.write_text(text)
    return path


@pytest.mark.parametrize(("n", "step_deg"), [(180, 1.0), (181, 1.0), (360, 0.5), (361, 0.5)])
def test_flaser_beams_span_180_deg_centred(tmp_path, n, step_deg):
    log = write(tmp_path / "a.log", [flaser(np.full(n, 2.0), 1.0)])
    (scan,) = list(open_log(log))
    np.testing.assert_allclose(np.diff(np.degrees(scan.angles)), step_deg, atol=1e-9)
    np.testing.assert_allclose(scan.angles[0], -scan.angles[-1], atol=1e-12)
    assert scan.num_beams == n and scan.stamp == pytest.approx(1.0)


def test_flaser_ranges_reference_and_odometry(tmp_path):
    lines = [odom(0.0, 0.0, 0.0, 0.5), flaser([1.0, 81.91, 3.0], 1.0, pose=(1.0, 2.0, 0.5)),
             odom(0.1, 0.0, 0.0, 1.2), flaser([2.0, 2.0, 2.0], 2.0, pose=(1.5, 2.0, 0.6))]
    log = write(tmp_path / "x-corrected.log.gz", lines, gz=True)
    source = open_log(log)
    assert source.format == "carmen" and source.topic == "FLASER"
    scans = list(source)
    np.testing.assert_allclose(scans[0].ranges, [1.0, 81.91, 3.0], rtol=1e-6)
    # 81.91 m is the SICK "no return" code, beyond the 80 m FLASER range limit
    np.testing.assert_array_equal(scans[0].valid_mask, [True, False, True])
    np.testing.assert_allclose(source.reference.poses, [[1.0, 2.0, 0.5], [1.5, 2.0, 0.6]])
    np.testing.assert_allclose(source.reference.stamps, [1.0, 2.0])
    np.testing.assert_allclose(source.odometry.stamps, [0.5, 1.2])
    np.testing.assert_allclose(source.odometry.poses[1], [0.1, 0.0, 0.0])


def test_reference_only_for_corrected_logs(tmp_path):
    log = write(tmp_path / "raw.log", [flaser([1.0, 1.0, 1.0], 1.0)])
    assert open_log(log).reference is None
    forced = CarmenLog(log, config=CarmenConfig(corrected=True))
    assert len(forced.reference) == 1


def test_robotlaser_angles_max_range_and_laser_pose(tmp_path):
    log = write(tmp_path / "r-corrected.clf", [
        robotlaser([1.0, 20.0, 2.5, 3.0], 5.0, start=-1.0, res=0.01),
        flaser([1.0, 1.0, 1.0], 5.1),  # same laser twice: ROBOTLASER1 is preferred
    ])
    source = open_log(log)
    assert source.topic == "ROBOTLASER1"
    (scan,) = list(source)
    np.testing.assert_allclose(scan.angles, [-1.0, -0.99, -0.98, -0.97])
    assert scan.range_max == 20.0
    np.testing.assert_array_equal(scan.valid_mask, [True, False, True, True])  # 20 = max: no return
    np.testing.assert_allclose(source.reference.poses, [[3.0, 4.0, 0.1]])
    flaser_only = list(open_log(log, topic="FLASER"))
    assert len(flaser_only) == 1 and flaser_only[0].num_beams == 3
    assert {t["name"]: t["count"] for t in source.topics()} == {"ROBOTLASER1": 1, "FLASER": 1}


def test_rawlaser(tmp_path):
    log = write(tmp_path / "raw.log", [rawlaser([1.0, 2.0, 3.0], 1.0), rawlaser([1, 2, 3], 2.0)])
    scans = list(open_log(log))
    assert [s.stamp for s in scans] == [1.0, 2.0]
    np.testing.assert_allclose(scans[0].angles, [-0.5, 0.0, 0.5])


def test_unknown_topic_is_a_clear_error(tmp_path):
    log = write(tmp_path / "a.log", [flaser([1.0], 1.0)])
    with pytest.raises(ValueError, match="unknown CARMEN laser message 'LASER9'"):
        open_log(log, topic="LASER9")


def _bad_log(tmp_path):
    return write(tmp_path / "bad.log", [
        flaser([1.0, 1.0, 1.0], 1.0),
        "FLASER 3 1.0 oops 1.0 0 0 0 0 0 0 2.0 host 2.0\n",  # line 4: malformed
        "FLASER 5 1.0 1.0 1.0 0 0 0 0 0 0 3.0 host 3.0\n",   # line 5: declares 5, holds 3
        flaser([np.nan, np.inf, 2.0], 4.0),                  # NaN/inf beams: kept, invalid
        "FLASER 0 0 0 0 0 0 0 5.0 host 5.0\n",               # line 7: empty scan
        flaser([0.0, np.inf, np.nan], 6.0),                  # line 8: nothing valid
        flaser([1.0, 1.0, 1.0], 7.0),
        flaser([1.0, 1.0, 1.0], 1.5),                        # line 10: 5.5 s back in time
        flaser([1.0, 1.0, 1.0], 7.0),                        # line 11: repeated stamp
        flaser([1.0, 1.0, 1.0], 8.0),
    ])


def test_bad_records_are_skipped_and_counted(tmp_path):
    source = open_log(_bad_log(tmp_path))
    scans = list(source)
    # the stamp 5.5 s back in time and one of the repeated ones are repaired from their
    # neighbours (6.0 on line 8, 7.0 on line 11), not dropped
    np.testing.assert_allclose([s.stamp for s in scans], [1.0, 4.0, 19 / 3, 20 / 3, 7.0, 8.0])
    np.testing.assert_array_equal(scans[1].valid_mask, [False, False, True])
    assert scans[1].endpoints().shape == (1, 2)
    assert source.skipped == {MALFORMED: 1, WRONG_BEAM_COUNT: 1, EMPTY_SCAN: 1,
                              NO_VALID_RETURNS: 1}
    assert source.records_seen == 10 and source.scans_read == 6
    assert source.skip_examples[MALFORMED].startswith("line 4:")
    assert "oops" in source.skip_examples[MALFORMED]
    assert source.skip_examples[WRONG_BEAM_COUNT].startswith("line 5:")
    assert source.time_source.startswith("log stamps (2 repaired")
    assert any("2 repaired" in note for note in source.notes())


def test_strict_mode_raises_naming_file_and_line(tmp_path):
    log = _bad_log(tmp_path)
    with pytest.raises(ValueError, match=r"bad\.log: line 4: malformed record.*oops"):
        list(open_log(log, strict=True))


def test_scans_stamped_before_the_one_ahead_keep_their_place(tmp_path):
    """A scanner delivers in order: of two scans whose stamps disagree with their order one
    has a wrong stamp, repaired between its neighbours; no scan changes place."""
    stamps = (1.0, 2.0, 1.5, 3.0, 2.9, 4.0)
    log = write(tmp_path / "a.log", [flaser([k + 1.0], t) for k, t in enumerate(stamps)])
    source = open_log(log)
    scans = list(source)
    assert [float(s.ranges[0]) for s in scans] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    out = np.array([s.stamp for s in scans])
    assert np.all(np.diff(out) > 0) and np.count_nonzero(out == np.array(stamps)) == 4
    assert source.skipped == {}
    assert any("2 repaired" in note for note in source.info()["notes"])


def test_truncated_gzip_keeps_what_was_read(tmp_path):
    lines = [flaser(np.full(181, 3.0), 1.0 + 0.1 * k) for k in range(400)]
    log = write(tmp_path / "full.log.gz", lines, gz=True)
    data = log.read_bytes()
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(data[: len(data) // 2])
    source = open_log(cut)
    scans = list(source)
    assert 0 < len(scans) < 400
    assert source.skipped.get(TRUNCATED) == 1
    assert "after line" in source.skip_examples[TRUNCATED]
    # the partly written last line is skipped as malformed or wrong length, never returned
    assert all(s.num_beams == 181 for s in scans)


def test_real_freiburg_log():
    source = open_log(shared_log("freiburg-079-corrected.log.gz"))
    scans = list(source)
    assert len(scans) == 4791
    assert all(s.num_beams == 360 for s in scans)
    assert np.all(np.diff([s.stamp for s in scans]) > 0)
    assert len(source.reference) == 4791
    assert len(source.odometry) > 4000  # 9725 ODOM lines, half of them stamped 0
    # the corrected path is about as long as the ~1 km building survey, not zero or absurd
    assert 50.0 < source.reference.path_length() < 5000.0


def test_real_intel_log():
    source = open_log(shared_log("intel-corrected.log.gz"))
    assert sum(1 for _ in source) == 910
    assert len(source.reference) == 910


def test_robotlaser_with_counts_that_do_not_fit_the_line(tmp_path):
    good = robotlaser([1.0, 2.0, 3.0], 1.0)
    fields = good.split()
    fields[8] = "7"  # declares 7 beams, holds 3
    log = write(tmp_path / "r.log", [" ".join(fields) + "\n", robotlaser([1.0, 2.0], 2.0)])
    source = open_log(log)
    assert [s.num_beams for s in source] == [2]
    assert source.skip_examples[WRONG_BEAM_COUNT].startswith("line 3: wrong beam count")


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("line", [flaser, robotlaser])
def test_a_range_beyond_float32_is_an_invalid_beam_without_a_warning(tmp_path, line):
    # A corrupt digit run (1e50) overflows float32: the beam is invalid, the others kept.
    log = write(tmp_path / "a.log", [line([1.0, 1e50, 3.0], 1.0)])
    (scan,) = list(open_log(log))
    np.testing.assert_array_equal(scan.valid_mask, [True, False, True])
    np.testing.assert_allclose(scan.ranges[[0, 2]], [1.0, 3.0])
