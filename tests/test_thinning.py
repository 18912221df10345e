"""Tests of thinning a log to one scan per distance or angle travelled, and of `bioslam thin`."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from bioslam.geometry import between
from bioslam.io.logs import open_log
from bioslam.io.tum import read_tum
from bioslam.sim import load_world, make_adversarial_route
from bioslam.thinning import thin_indices


def test_straight_line_keeps_one_scan_per_metre():
    x = np.arange(101) * 0.1  # 10 m in steps of 0.1 m
    poses = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    assert thin_indices(poses, distance=1.0).tolist() == list(range(0, 101, 10))
    assert thin_indices(poses, distance=2.5).tolist() == [0, 25, 50, 75, 100]


def test_spin_on_the_spot_keeps_one_scan_per_angle_and_wraps():
    heading = np.deg2rad(np.arange(0.0, 721.0, 5.0))  # two full turns, wrapped below
    poses = np.column_stack([np.zeros_like(heading), np.zeros_like(heading), heading])
    poses[:, 2] = np.angle(np.exp(1j * poses[:, 2]))
    keep = thin_indices(poses, angle=np.deg2rad(20.0))
    assert keep.tolist() == list(range(0, len(poses), 4))
    assert thin_indices(poses, distance=1.0).tolist() == [0]  # it never moves


def test_distance_is_travelled_along_the_path_and_either_criterion_keeps():
    # Out 0.5 m and back: back where it started, but a metre travelled.
    x = np.concatenate([np.arange(6) * 0.1, 0.5 - np.arange(1, 6) * 0.1])
    poses = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    assert thin_indices(poses, distance=1.0).tolist() == [0, 10]
    # A turn in the middle of a straight line triggers the angle criterion there.
    turn = np.column_stack([np.arange(10) * 0.1, np.zeros(10), np.where(np.arange(10) < 3, 0, 0.5)])
    assert thin_indices(turn, distance=0.5, angle=0.4).tolist() == [0, 3, 8]


def test_thinning_needs_positive_thresholds():
    poses = np.zeros((5, 3))
    with pytest.raises(ValueError, match="distance or an angle"):
        thin_indices(poses)
    with pytest.raises(ValueError, match="positive"):
        thin_indices(poses, distance=-1.0)
    assert thin_indices(np.zeros((0, 3)), distance=1.0).size == 0


def test_kept_scans_are_as_far_apart_as_the_route_implies():
    world = load_world("maze")
    route = make_adversarial_route(world, duration=120.0, seed=2)
    stamps = np.arange(0.0, 120.0, 0.1)
    poses = route.pose_at(stamps)
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    travelled = np.concatenate([[0.0], np.cumsum(step)])
    keep = thin_indices(poses, distance=1.0)
    gaps = np.diff(travelled[keep])
    assert gaps.min() >= 1.0 - 1e-9 and gaps.max() < 1.0 + step.max()
    assert travelled[-1] - travelled[keep[-1]] < 1.0
    assert len(keep) == pytest.approx(travelled[-1], abs=0.1 * travelled[-1])


# -- the command ------------------------------------------------------------------------------


def run_cli(module: str, *argv: str) -> dict:
    import importlib

    parser = argparse.ArgumentParser()
    importlib.import_module(f"bioslam.cli.{module}").register(parser.add_subparsers(dest="cmd"))
    args = parser.parse_args([module, *argv])
    return args.func(args)


def carmen_log(path: Path, message: str, n: int = 40) -> None:
    """A corrected CARMEN log: a robot driving 0.25 m per scan and turning, ODOM between."""
    rng = np.random.default_rng(0)
    lines = ["# a test log", "PARAM robot_front_laser_max 80.0"]
    for k in range(n):
        t = 100.0 + 0.2 * k
        x, y, th = 0.25 * k, 0.01 * k * k, 0.05 * k
        lines.append(f"ODOM {x + 0.1} {y} {th} 0.1 0 0 {t - 0.05:.3f} host {t - 0.05:.3f}")
        ranges = " ".join(f"{r:.2f}" for r in rng.uniform(0.5, 20.0, 181))
        if message == "FLASER":
            lines.append(f"FLASER 181 {ranges} {x} {y} {th} {x} {y} {th} {t:.3f} host {t:.3f}")
        else:
            lines.append(
                f"ROBOTLASER1 0 -1.5708 3.14159 0.0174533 30.0 0.01 0 181 {ranges} 0 "
                f"{x} {y} {th} {x} {y} {th} 0 0 0 0 0 {t:.3f} host {t:.3f}"
            )
    path.write_text("\n".join(lines) + "\n")


def assert_same_scans(got, want) -> None:
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        assert a.stamp == b.stamp
        assert np.array_equal(a.ranges, b.ranges, equal_nan=True)
        np.testing.assert_allclose(a.angles, b.angles, atol=1e-12)
        assert a.range_max == pytest.approx(b.range_max)


@pytest.mark.parametrize("message", ["FLASER", "ROBOTLASER1"])
def test_thin_a_carmen_log_keeps_its_reference_and_odometry(tmp_path, message):
    src = tmp_path / "walk-corrected.log"
    carmen_log(src, message)
    out = tmp_path / "walk-thin-corrected.log.gz"
    summary = run_cli("thin", str(src), "--out", str(out), "--distance", "1.0", "--angle", "30")
    original = open_log(src)
    scans = list(original)
    keep = thin_indices(original.reference.poses, 1.0, np.deg2rad(30.0))
    assert summary["by"] == "reference"
    assert summary["scans_kept"] == len(keep) < len(scans)
    thinned = open_log(out)
    assert_same_scans(list(thinned), [scans[i] for i in keep])
    np.testing.assert_array_equal(thinned.reference.poses, original.reference.poses[keep])
    np.testing.assert_array_equal(thinned.odometry.stamps, original.odometry.stamps)
    np.testing.assert_array_equal(thinned.odometry.poses, original.odometry.poses)
    # Thinning by the odometry measures the motion along it instead.
    by_odo = run_cli("thin", str(src), "--out", str(tmp_path / "o-corrected.log"),
                     "--distance", "1.0", "--by", "odometry")  # fmt: skip
    want = thin_indices(original.odometry.at(original.reference.stamps).poses, 1.0)
    assert by_odo["scans_kept"] == len(want)


def test_thin_refuses_names_that_would_lose_or_invent_a_reference(tmp_path):
    src = tmp_path / "walk-corrected.log"
    carmen_log(src, "FLASER", n=5)
    with pytest.raises(ValueError, match="corrected"):
        run_cli("thin", str(src), "--out", str(tmp_path / "walk-thin.log"), "--distance", "1")
    with pytest.raises(FileNotFoundError, match="TUM file"):
        run_cli("thin", str(src), "--out", str(tmp_path / "x-corrected.log"), "--distance", "1",
                "--by", str(tmp_path / "missing.tum"))  # fmt: skip


def test_thin_a_simulated_bag_by_its_ground_truth(tmp_path):
    sim = tmp_path / "sim"
    run_cli("sim", "--world", "hall", "--route", "adversarial", "--lidar", "sick",
            "--duration", "6", "--seed", "2", "--out", str(sim))  # fmt: skip
    out = tmp_path / "thin"
    summary = run_cli("thin", str(sim / "scans"), "--by", str(sim / "gt.tum"), "--out", str(out),
                      "--distance", "0.5", "--angle", "20")  # fmt: skip
    gt = read_tum(sim / "gt.tum")
    keep = thin_indices(gt.poses, 0.5, np.deg2rad(20.0))
    assert 3 <= summary["scans_kept"] == len(keep) < 60
    steps = between(gt.poses[keep[:-1]], gt.poses[keep[1:]])
    turns = np.degrees(np.abs(steps[:, 2]))
    assert summary["largest_turn_deg"] == pytest.approx(turns.max(), abs=0.05)
    assert summary["largest_step_m"] == pytest.approx(np.hypot(*steps[:, :2].T).max(), abs=5e-4)
    original = list(open_log(sim / "scans"))
    assert_same_scans(list(open_log(out / "scans")), [original[i] for i in keep])
    thinned_gt = read_tum(out / "gt.tum")
    np.testing.assert_allclose(thinned_gt.poses, gt.poses[keep], atol=1e-9)
    np.testing.assert_allclose(thinned_gt.stamps, gt.stamps[keep], atol=1e-9)
