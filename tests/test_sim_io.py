"""Simulator I/O: the ROS 2 bag writer, worlds from map files and the ``bioslam sim`` command."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bioslam.io.bag_writer import ScanBagWriter, write_scan_bag
from bioslam.io.mapfile import OccupancyImage, write_map
from bioslam.io.tum import read_tum
from bioslam.scan import LaserScan
from bioslam.sim import LIDAR_PRESETS, make_route, maze_world, simulate_scans, world_from_map
from bioslam.sim.raycast import cast_rays


def simulated(duration: float = 1.0, lidar: str = "utm30lx") -> list[LaserScan]:
    world = maze_world()
    route = make_route(world, duration=duration, seed=2)
    model = replace(LIDAR_PRESETS[lidar], dropout_prob=0.05, range_max=3.0)
    return [scan for scan, _ in simulate_scans(world, model, route, seed=2)]


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_bag_round_trip(tmp_path, storage):
    logs = pytest.importorskip("bioslam.io.logs")
    pytest.importorskip("bioslam.io.rosbag", reason="the ROS bag reader is not there yet")
    scans = simulated()
    bag = tmp_path / "scans"
    assert write_scan_bag(bag, scans, scan_time=0.025, storage=storage) == len(scans)
    back = list(logs.open_log(bag))
    assert len(back) == len(scans)
    for a, b in zip(scans, back, strict=True):
        assert b.stamp == pytest.approx(a.stamp, abs=1e-9)
        # NaN dropouts and inf no-returns survive, values bit for bit (float32 both ways).
        np.testing.assert_array_equal(np.asarray(b.ranges, np.float32), a.ranges)
        np.testing.assert_allclose(b.angles, a.angles, atol=1e-6)
        assert b.time_increment == pytest.approx(a.time_increment, rel=1e-6)
        assert (b.range_min, b.range_max) == pytest.approx((a.range_min, a.range_max))


def test_bag_writer_refuses_bad_input(tmp_path):
    bag = tmp_path / "scans"
    bag.mkdir()
    with pytest.raises(FileExistsError):
        ScanBagWriter(bag)
    with pytest.raises(ValueError, match="storage"):
        ScanBagWriter(tmp_path / "other", storage="zip")
    uneven = LaserScan(1.0, np.ones(3), np.array([0.0, 0.1, 0.3]))
    with (
        pytest.raises(ValueError, match="evenly spaced"),
        ScanBagWriter(tmp_path / "b2") as writer,
    ):
        writer.write(uneven)


def room_with_pillar(tmp_path: Path) -> tuple[OccupancyImage, Path]:
    """An 8 m x 6 m room (walls 0.1 m thick) with a 2 m x 1 m pillar centred at (4, 3)."""
    res = 0.05
    occ = np.zeros((124, 164))
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = 1.0
    occ[52:72, 42:122] = 1.0  # y 2.5..3.5, x 2..6 with origin (-0.1, -0.1)
    occ[0, 0] = np.nan  # an unknown corner cell is a wall too
    image = OccupancyImage(occ, res, (-0.1, -0.1, 0.0))
    _, yaml = write_map(tmp_path / "room", image)
    return image, yaml


def test_world_from_map(tmp_path):
    _, yaml = room_with_pillar(tmp_path)
    world = world_from_map(yaml)
    # Only the inner faces of the outer walls can be seen: the map's outside counts as wall.
    assert world.bounds == pytest.approx((0.0, 0.0, 8.0, 6.0))
    hits = cast_rays(world.grid, np.array([[1.0, 3.0], [4.0, 1.0]]), np.array([0.0, np.pi / 2]))
    np.testing.assert_allclose(hits, [1.0, 1.5], atol=1e-9)  # the pillar's faces x=2, y=2.5
    route = make_route(world, duration=200.0, seed=0)
    xy = route.pose_at(np.linspace(0.0, 200.0, 4000))[:, :2]
    assert world.distance_to_walls(xy).min() >= 0.3
    # The route goes round the pillar: its heading winds through full turns.
    turns = np.unwrap(np.arctan2(xy[:, 1] - 3.0, xy[:, 0] - 4.0))
    assert np.ptp(turns) > 2 * np.pi


def test_world_from_map_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        world_from_map(tmp_path / "missing.yaml")
    image = OccupancyImage(np.zeros((20, 20)), 0.05)
    _, yaml = write_map(tmp_path / "empty", image)
    with pytest.raises(ValueError, match="no occupied cells"):
        world_from_map(yaml)


def run_cli(*argv: str) -> dict:
    from bioslam.cli import sim

    parser = argparse.ArgumentParser()
    sim.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["sim", *argv])
    return args.func(args)


def test_sim_command_writes_bag_ground_truth_and_figure(tmp_path):
    out = tmp_path / "run"
    summary = run_cli(
        "--lidar", "rplidar", "--duration", "5", "--seed", "1", "--noise", "0", "--out", str(out)
    )
    assert summary["scans"] == 35  # 7 Hz for 5 s, the last sweep ending just in time
    assert summary["path_length_m"] == pytest.approx(2.5, abs=0.6)  # 0.5 m/s after speeding up
    gt = read_tum(out / "gt.tum")
    assert len(gt) == summary["scans"]
    np.testing.assert_allclose(np.diff(gt.stamps), 1 / 7)
    assert (out / "world.png").stat().st_size > 10_000
    assert (out / "scans" / "metadata.yaml").is_file()
    with pytest.raises(ValueError, match="--force"):
        run_cli("--duration", "1", "--out", str(out))
    again = run_cli("--lidar", "urg04lx", "--duration", "1", "--out", str(out), "--force")
    assert again["scans"] == 10


def test_sim_command_writes_the_ground_truth_of_a_scanner_mounted_sideways(tmp_path):
    out = tmp_path / "run"
    run_cli("--duration", "2", "--seed", "1", "--out", str(out))
    robot = read_tum(out / "gt.tum")
    summary = run_cli(
        "--duration", "2", "--seed", "1", "--mount-yaw", "90", "--out", str(out), "--force"
    )
    assert summary["mount_yaw_deg"] == 90.0
    scanner = read_tum(out / "gt.tum")
    np.testing.assert_allclose(scanner.poses[:, :2], robot.poses[:, :2])
    turned = np.angle(np.exp(1j * (scanner.poses[:, 2] - robot.poses[:, 2])))
    np.testing.assert_allclose(turned, np.pi / 2, atol=1e-5)  # TUM stores float text


def test_sim_command_rejects_unknown_world(tmp_path):
    with pytest.raises(ValueError, match="maze"):
        run_cli("--world", "plan.txt", "--out", str(tmp_path))


def test_sim_command_on_a_map_file(tmp_path):
    _, yaml = room_with_pillar(tmp_path)
    out = tmp_path / "run"
    summary = run_cli(
        "--world", str(yaml), "--lidar", "urg04lx", "--duration", "3", "--out", str(out)
    )
    assert summary["world"] == yaml.stem and summary["scans"] == 30
    gt = read_tum(out / "gt.tum")
    world = world_from_map(yaml)
    assert world.distance_to_walls(gt.poses[:, :2]).min() >= 0.3


def test_rotated_map_origin_rotates_the_world(tmp_path):
    image, _ = room_with_pillar(tmp_path)
    turned = OccupancyImage(image.occupancy, image.resolution, (-0.1, -0.1, np.pi / 2))
    _, yaml = write_map(tmp_path / "turned", turned)
    world = world_from_map(yaml)
    # Rotating by +90 degrees about the origin (-0.1, -0.1) maps x -> y and y -> -x.
    assert world.bounds == pytest.approx((-6.2, 0.0, -0.2, 8.0))
