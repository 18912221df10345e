"""Tests of the repetitive worlds, the SICK presets and the adversarial routes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bioslam.sim import (
    LIDAR_PRESETS,
    WORLDS,
    AdversarialConfig,
    Route,
    World,
    load_world,
    make_adversarial_route,
    rooms_world,
    true_ranges,
    warehouse_world,
)
from bioslam.sim.raycast import cast_rays
from bioslam.sim.rooms import ROOM, room_origins
from bioslam.sim.warehouse import BAY, CROSS_AISLE, RACK_LENGTH, aisle_centres


def static_route(pose: tuple[float, float, float]) -> Route:
    return Route(np.array([0.0, 1.0]), np.array([pose, pose], dtype=float))


def exact_scan(world: World, lidar: str, pose: tuple[float, float, float]) -> np.ndarray:
    model = replace(LIDAR_PRESETS[lidar], noise_sigma=0.0, sweep=False)
    ranges, _ = true_ranges(world, model, static_route(pose), np.array([0.0]))
    return ranges[0]


def assert_same_view(a: np.ndarray, b: np.ndarray) -> None:
    assert np.array_equal(np.isinf(a), np.isinf(b))
    np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], atol=1e-6)


# -- worlds -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def warehouse() -> World:
    return warehouse_world()


@pytest.mark.parametrize("heading", [0.0, 0.3, np.pi / 2, 2.5])
def test_warehouse_aisles_look_identical(warehouse, heading):
    ys = aisle_centres()
    x = CROSS_AISLE + 0.5 * RACK_LENGTH + 0.37
    views = [exact_scan(warehouse, "sick", (x, y, heading)) for y in ys[2:5]]
    assert np.isfinite(views[0]).sum() > 150  # the 80 m scanner sees walls nearly everywhere
    for other in views[1:]:
        assert_same_view(views[0], other)


def test_warehouse_loading_bay_breaks_the_symmetry(warehouse):
    """The one aisle that looks down onto the loading bay sees it (so the test above could
    fail: aisles are compared over the whole 80 m reach of the scanner)."""
    ys = aisle_centres()
    x = CROSS_AISLE + 0.5 * RACK_LENGTH
    bay_aisle = next(y for y in ys if 3.0 < y < 6.0)
    plain = exact_scan(warehouse, "sick", (x, ys[3], 0.0))
    facing_bay = exact_scan(warehouse, "sick", (x, bay_aisle, 0.0))
    assert np.abs(plain - facing_bay).max() > 0.5


def test_warehouse_view_repeats_every_bay_and_the_end_is_out_of_reach(warehouse):
    y = aisle_centres()[2]
    x = CROSS_AISLE + 3.3 * BAY
    side = exact_scan(warehouse, "urg04lx", (x, y, np.pi / 2))
    assert_same_view(side, exact_scan(warehouse, "urg04lx", (x + BAY, y, np.pi / 2)))
    assert not np.allclose(side, exact_scan(warehouse, "urg04lx", (x + 0.5 * BAY, y, np.pi / 2)))
    # Looking down the aisle: no end wall for a 5.6 m scanner mid-aisle, nor for a 30 m one
    # near the west end.
    ahead = cast_rays(warehouse.grid, np.array([[x, y], [CROSS_AISLE + 1.0, y]]),
                      np.array([0.0, 0.0]))  # fmt: skip
    assert ahead[0] > 5.6 and ahead[1] > 30.0


def test_identical_rooms_off_the_corridor():
    world = rooms_world()
    width, depth = ROOM
    xs = room_origins()
    views = [exact_scan(world, "urg04lx", (x + 0.5 * width, 0.5 * depth, 0.7)) for x in xs[2:6]]
    assert np.isfinite(views[0]).sum() > 0.8 * len(views[0])
    for other in views[1:]:
        assert_same_view(views[0], other)
    # The north rooms are mirror images: from the mirrored pose the scan is the reversed one.
    _, height = world.bounds[2:]
    north = exact_scan(world, "urg04lx", (xs[3] + 0.5 * width, height - 0.5 * depth, -0.7))
    assert_same_view(views[0], north[::-1])


def test_built_in_worlds_load_by_name_and_have_loops():
    for name in WORLDS:
        world = load_world(name)
        assert world.name == name
        road = world.roadmap
        assert np.bincount(road.edges.ravel()).min() >= 2  # no dead ends
        assert len(road.edges) - len(road.nodes) + 1 >= 3  # independent loops
        assert road.clearance.min() >= 0.6 - 1e-9  # room for a route's corner arcs
    with pytest.raises(ValueError, match="warehouse"):
        load_world("nowhere")


# -- the SICK presets -------------------------------------------------------------------------


def test_sick_presets_beam_geometry():
    sick = LIDAR_PRESETS["sick"]
    angles = np.rad2deg(sick.angles())
    assert sick.beams == 181 and angles == pytest.approx(np.arange(-90.0, 90.5, 1.0))
    assert (sick.range_max, sick.rate_hz, sick.noise_sigma) == (80.0, 10.0, 0.01)
    # The 75 Hz mirror sweeps the 180 degrees in 1/150 s, not in a tenth of a second.
    assert sick.time_increment * (sick.beams - 1) == pytest.approx(1.0 / 150.0)
    fine = LIDAR_PRESETS["sick361"]
    assert fine.beams == 361
    assert np.rad2deg(fine.angles()) == pytest.approx(np.arange(-90.0, 90.25, 0.5))
    # A wall 60 m ahead is in range; beams beyond the 180 degrees see nothing behind.
    hall = World(np.array([[60.0, -50.0, 60.0, 50.0], [-1.0, -50.0, -1.0, 50.0]]))
    ranges = exact_scan(hall, "sick", (0.0, 0.0, 0.0))
    assert ranges[90] == pytest.approx(60.0)
    assert np.isinf(ranges[[0, -1]]).all()  # parallel to both walls


# -- adversarial routes -----------------------------------------------------------------------


def offsets_from_centre_lines(world: World, xy: np.ndarray) -> np.ndarray:
    """Distance to the roadmap's edges, away from its nodes (where corner arcs cut across)."""
    road = world.roadmap
    edges = np.hstack([road.nodes[road.edges[:, 0]], road.nodes[road.edges[:, 1]]])
    to_node = np.hypot(*(xy[:, None, :] - road.nodes[None]).transpose(2, 0, 1)).min(axis=1)
    return World(edges).distance_to_walls(xy[to_node > 1.0])


def crosses_a_wall(world: World, xy: np.ndarray) -> bool:
    """Does any straight step between consecutive points pass through a wall?"""
    step = np.diff(xy, axis=0)
    length = np.hypot(*step.T)
    moving = length > 1e-9
    hit = cast_rays(world.grid, xy[:-1][moving], np.arctan2(step[moving, 1], step[moving, 0]))
    return bool((hit < length[moving]).any())


@pytest.fixture(scope="module")
def warehouse_route(warehouse) -> Route:
    return make_adversarial_route(warehouse, duration=300.0, seed=3)


def test_adversarial_route_stays_in_free_space_within_limits(warehouse, warehouse_route):
    route, cfg = warehouse_route, AdversarialConfig()
    t = np.arange(0.0, route.duration, 0.01)
    poses = route.pose_at(t)
    assert not crosses_a_wall(warehouse, poses[:, :2])
    assert warehouse.distance_to_walls(poses[:, :2]).min() >= cfg.route.clearance
    speed = np.hypot(*np.diff(poses[:, :2], axis=0).T) / 0.01
    yaw_rate = np.abs(np.diff(np.unwrap(poses[:, 2]))) / 0.01
    assert speed.max() <= cfg.fast_speed + 1e-6 and speed.max() > 0.95 * cfg.fast_speed
    assert yaw_rate.max() <= cfg.spin_rate + 1e-6
    # Turns on the spot: fast yaw while standing still, then driving off.
    spinning = (yaw_rate > 0.9 * cfg.spin_rate) & (speed < 1e-6)
    assert spinning.sum() * 0.01 > 5.0
    # While driving, the heading follows the direction of travel.
    moving = speed > 0.05
    step = np.diff(poses[:, :2], axis=0)
    travel = np.arctan2(step[:, 1], step[:, 0])
    assert np.abs(np.angle(np.exp(1j * (travel - poses[1:, 2]))))[moving].max() < 0.05


def test_adversarial_route_weaves_to_the_configured_offsets(warehouse, warehouse_route):
    xy = warehouse_route.pose_at(np.arange(0.0, warehouse_route.duration, 0.05))[:, :2]
    off = offsets_from_centre_lines(warehouse, xy)
    assert off.max() == pytest.approx(0.5, abs=0.02)  # the aisles have room for all of it
    assert np.mean(off > 0.25) > 0.25  # much of the time well off the centre-line
    tight = make_adversarial_route(
        warehouse, duration=120.0, seed=3, config=AdversarialConfig(lateral_offset=0.2)
    )
    xy = tight.pose_at(np.arange(0.0, 120.0, 0.05))[:, :2]
    assert offsets_from_centre_lines(warehouse, xy).max() == pytest.approx(0.2, abs=0.02)


def turned_back(route: Route, radius: float = 0.3) -> int:
    """Places passed again 5-60 s later heading the opposite way (within 30 deg): a robot
    that turned back, not one that came round a loop the other way much later."""
    t = np.arange(0.0, route.duration, 0.5)
    poses = route.pose_at(t)
    near = np.hypot(*(poses[:, None, :2] - poses[None, :, :2]).transpose(2, 0, 1)) < radius
    dt = t[None, :] - t[:, None]
    opposite = np.abs(np.angle(np.exp(1j * (poses[:, None, 2] - poses[None, :, 2] - np.pi))))
    soon = (dt > 5.0) & (dt < 60.0)
    return int((near & soon & (opposite < np.deg2rad(30.0))).any(axis=1).sum())


def test_adversarial_route_turns_back_to_revisit_places_the_other_way(warehouse,
                                                                     warehouse_route):
    assert turned_back(warehouse_route) >= 20
    never = make_adversarial_route(
        warehouse, duration=300.0, seed=3, config=AdversarialConfig(turn_back_every=1e9)
    )
    assert turned_back(never) <= 2  # aisles are long: only turn-backs come back so soon


def pillar_room() -> World:
    """A map_server-style occupancy map: an 8 m x 6 m room round a 4 m x 1 m pillar."""
    from bioslam.io.mapfile import OccupancyImage
    from bioslam.sim import world_from_occupancy

    occ = np.zeros((120, 160))
    occ[:2, :] = occ[-2:, :] = occ[:, :2] = occ[:, -2:] = 1.0
    occ[50:70, 40:120] = 1.0
    return world_from_occupancy(OccupancyImage(occ, 0.05, (0.0, 0.0, 0.0)))


def test_adversarial_route_in_every_world_is_deterministic():
    for world in [*(load_world(name) for name in ("maze", "rooms", "hall")), pillar_room()]:
        a = make_adversarial_route(world, duration=60.0, seed=1)
        b = make_adversarial_route(world, duration=60.0, seed=1)
        t = np.linspace(0.0, 60.0, 400)
        assert np.array_equal(a.pose_at(t), b.pose_at(t))
        assert not crosses_a_wall(world, a.pose_at(np.arange(0.0, 60.0, 0.01))[:, :2])


def test_adversarial_config_is_checked():
    with pytest.raises(ValueError, match="spin_prob"):
        AdversarialConfig(spin_prob=1.5)
    with pytest.raises(ValueError, match="turn_back_every"):
        AdversarialConfig(turn_back_every=0.0)
    with pytest.raises(ValueError, match="swing"):
        AdversarialConfig(swing=(0.0, 1.0))
    with pytest.raises(ValueError, match="roadmap"):
        make_adversarial_route(World(np.array([[0.0, 0.0, 1.0, 0.0]])), duration=10.0)


def test_sim_command_simulates_a_named_world_and_route(tmp_path):
    import argparse

    from bioslam.cli import sim
    from bioslam.io.logs import open_log

    parser = argparse.ArgumentParser()
    sim.register(parser.add_subparsers(dest="command"))
    out = tmp_path / "rooms"
    args = parser.parse_args(["sim", "--world", "rooms", "--route", "adversarial", "--lidar",
                              "sick", "--duration", "3", "--lateral-offset", "0.3",
                              "--out", str(out)])  # fmt: skip
    summary = args.func(args)
    assert (summary["world"], summary["route"], summary["scans"]) == ("rooms", "adversarial", 30)
    scans = list(open_log(out / "scans"))
    assert len(scans) == 30 and scans[0].num_beams == 181
    assert scans[0].time_increment == pytest.approx(1.0 / 75.0 / 360.0)
    tour = parser.parse_args(["sim", "--lateral-offset", "0.3", "--out", str(tmp_path / "t")])
    with pytest.raises(ValueError, match="adversarial"):
        tour.func(tour)


def test_the_command_line_loads_no_heavy_library_until_a_command_needs_it():
    """Building the parser (``bioslam --help``, and before every command) must not import
    Numba, SciPy, rosbags or Matplotlib: they cost 100 MB before the first scan."""
    import subprocess
    import sys

    code = (
        "import sys, bioslam.cli as c; c.build_parser(); "
        "print(sorted({m.split('.')[0] for m in sys.modules} "
        "& {'numba', 'scipy', 'rosbags', 'matplotlib', 'ray'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_command_line_names_match_the_registries():
    from bioslam.cli.sim import ROUTE_NAMES, STORAGE_NAMES
    from bioslam.io.bag_writer import STORAGES
    from bioslam.sim import ROUTES

    assert set(ROUTE_NAMES) == set(ROUTES)
    assert set(STORAGE_NAMES) == set(STORAGES)
