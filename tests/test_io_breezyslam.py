"""BreezySLAM .dat reader: beams, units, wheel odometry, bad input, the shared exp1 log."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _io_data import shared_log

from bioslam.io.breezyslam import BreezySlamConfig, integrate_wheel_odometry
from bioslam.io.logs import MALFORMED, WRONG_BEAM_COUNT, open_log

CFG = BreezySlamConfig()
METRES_PER_TICK = 2 * math.pi * CFG.wheel_radius_m / CFG.ticks_per_rev


def line(t_us, left, right, ranges_mm=None) -> str:
    ranges = np.full(CFG.beams, 1500) if ranges_mm is None else ranges_mm
    status = [14000, left, right] + [0] * (CFG.status_fields - 3)
    return " ".join(str(v) for v in [t_us, *status, *ranges]) + "\n"


def test_beams_units_and_angles(tmp_path):
    ranges = np.full(CFG.beams, 2500)
    ranges[:10] = 0  # no return
    ranges[10] = 9000  # beyond the 5.6 m URG-04LX range
    path = tmp_path / "log.dat"
    path.write_text(line(1_000_000, 0, 0, ranges) + line(1_100_000, 0, 0))
    source = open_log(path)
    assert source.format == "breezyslam"
    scan = next(iter(source))
    assert scan.stamp == pytest.approx(1.0)
    assert scan.num_beams == 682
    assert np.degrees(scan.angles[0]) == pytest.approx(-120.0)
    assert np.degrees(scan.angles[-1]) == pytest.approx(120.0)
    assert scan.ranges[20] == pytest.approx(2.5)
    assert not scan.valid_mask[:11].any() and scan.valid_mask[11:].all()
    assert scan.time_increment == pytest.approx(0.1 / 1024)


def test_wheel_odometry_straight_and_turning(tmp_path):
    ticks = 1000  # half a wheel turn
    path = tmp_path / "log.dat"
    path.write_text(
        line(0, 5000, 7000)
        + line(100_000, 5000 + ticks, 7000 + ticks)  # both wheels forward: straight ahead
        + line(200_000, 5000, 7000 + 2 * ticks)  # left back, right forward: turn in place
    )
    odo = open_log(path).odometry
    d = ticks * METRES_PER_TICK
    np.testing.assert_allclose(odo.poses[1], [d, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(odo.poses[2, :2], [d, 0.0], atol=1e-12)
    assert odo.poses[2, 2] == pytest.approx(2 * d / (2 * CFG.half_axle_m))
    np.testing.assert_allclose(odo.stamps, [0.0, 0.1, 0.2])


def test_arc_integration_matches_the_circle():
    # 100 small steps along a quarter circle of radius 1 m end where the circle says.
    radius, half_axle, steps = 1.0, 0.2, 100
    arc = (math.pi / 2) / steps
    pose = (0.0, 0.0, 0.0)
    for _ in range(steps):
        pose = integrate_wheel_odometry(
            pose, arc * (radius - half_axle), arc * (radius + half_axle), half_axle
        )
    np.testing.assert_allclose(pose, [1.0, 1.0, math.pi / 2], atol=1e-4)


def test_bad_lines_are_skipped_and_counted(tmp_path):
    path = tmp_path / "bad.dat"
    short = " ".join(["2000000", *["0"] * 24, *["100"] * 600]) + "\n"
    garbage = line(3_000_000, 0, 0).replace("1500", "x15", 1)
    path.write_text(
        line(1_000_000, 0, 0) + short + garbage + line(4_000_000, 0, 0)
        + line(0, 0, 0) + line(5_000_000, 0, 0)
    )
    source = open_log(path)
    # the line stamped 0 between 4 s and 5 s is repaired, and its odometry follows it
    assert [s.stamp for s in source] == [1.0, 4.0, 4.5, 5.0]
    np.testing.assert_array_equal(source.odometry.stamps, [1.0, 4.0, 4.5, 5.0])
    assert source.skipped == {WRONG_BEAM_COUNT: 1, MALFORMED: 1}
    assert source.skip_examples[WRONG_BEAM_COUNT].startswith("line 2: wrong beam count: 625")
    assert source.skip_examples[MALFORMED].startswith("line 3:")
    with pytest.raises(ValueError, match=r"bad\.dat: line 2: wrong beam count"):
        list(open_log(path, strict=True))


def test_topic_does_not_apply(tmp_path):
    path = tmp_path / "a.dat"
    path.write_text(line(0, 0, 0))
    with pytest.raises(ValueError, match="single scan stream"):
        open_log(path, topic="/scan")


def test_real_exp1_log():
    source = open_log(shared_log("exp1.dat"))
    scans = list(source)
    assert len(scans) == 756
    assert {s.num_beams for s in scans} == {682}
    duration = scans[-1].stamp - scans[0].stamp
    assert duration == pytest.approx(74.6, abs=0.1)
    odo = source.odometry
    assert len(odo) == 756
    # a hand-driven rover: average speed well under 2 m/s, and it moved
    assert 0.05 < odo.path_length() / duration < 2.0
