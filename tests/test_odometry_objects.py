"""Objects that move (a person walking ahead) are not fused at the scanner's rate: the runs of
endpoints taken for objects, and a route through corridors people walk."""

from __future__ import annotations

import numpy as np
import pytest

from bioslam.geometry import compose
from bioslam.odometry import LidarOdometry, OdometryConfig
from bioslam.odometry.local_map import compact_runs


def _line(start, end, n):
    return np.linspace(start, end, n)


def test_a_short_run_apart_from_the_walls_is_an_object_and_a_wall_is_not():
    """Endpoints in beam order: a wall the map holds, a gap, a 0.4 m blob where it holds
    nothing, a gap, a 3 m new wall: only the blob is an object."""
    wall = _line((0.0, 2.0), (1.0, 2.0), 21)
    blob = _line((1.5, 1.0), (1.9, 1.0), 9)
    new_wall = _line((3.0, 2.0), (6.0, 2.0), 61)
    points = np.vstack([wall, blob, new_wall])
    new = np.r_[np.zeros(21, bool), np.ones(9, bool), np.ones(61, bool)]
    assert compact_runs(points, new, 0.15, 0.7) == [(21, 29)]


def test_a_short_run_that_continues_a_held_wall_is_no_object():
    """A wall's end come into view continues what the map holds: no object."""
    held = _line((0.0, 2.0), (1.0, 2.0), 21)
    extension = _line((1.05, 2.0), (1.3, 2.0), 6)
    points = np.vstack([held, extension])
    new = np.r_[np.zeros(21, bool), np.ones(6, bool)]
    assert compact_runs(points, new, 0.15, 0.7) == []
    assert compact_runs(np.zeros((0, 2)), np.zeros(0, bool), 0.15, 0.7) == []


def _maze_with_people(seed: int, object_size: float) -> float:
    from bioslam.sim import LIDAR_PRESETS, ROUTES, load_world, people_on_roadmap, simulate_scans

    world = load_world("maze")
    route = ROUTES["adversarial"](world, duration=600.0, seed=seed)
    people = people_on_roadmap(world, 3, seed=seed)
    items = list(simulate_scans(world, LIDAR_PRESETS["sick"], route, seed=seed, obstacles=people))
    truth = np.array([pose for _, pose in items])
    odo = LidarOdometry(OdometryConfig(object_size=object_size))  # at the origin, as `run`
    estimate = []
    for scan, _ in items:
        odo.update(scan)
        estimate.append(odo.pose.copy())
    moved = compose(truth[0], np.array(estimate))
    return float(np.hypot(*(moved[:, :2] - truth[:, :2]).T).max())


def test_people_walking_the_corridors_are_not_followed():
    """The maze's weaving route with a SICK at 10 Hz and three people walking its corridors
    (seed 412, a route made to find failures, not tuned on), started at the origin as
    ``bioslam run`` starts: a person walking ahead was fused wherever the map had not looked,
    the scans were matched onto that trail, and the odometry followed them (8 m off at
    worst); with the objects that moved since a fifth of a second before left out of the
    map, within 0.3 m."""
    assert _maze_with_people(412, 0.7) < 0.3
    assert _maze_with_people(412, 0.0) > 1.0


def _tour_with_people_on_its_own_route(object_near: float, until: float) -> tuple[float, float]:
    """The maze's tour, UTM-30LX, 120 s, seed 0, with three people walking stretches of the
    robot's own route back and forth (at 15-20 %, 45-50 % and 75-80 % of it): the largest
    position error up to ``until`` seconds, and the error then."""
    from bioslam.sim import LIDAR_PRESETS, load_world, make_route, people_on_route, simulate_scans

    world = load_world("maze")
    route = make_route(world, duration=120.0, seed=0, fast_turns=False)
    people = people_on_route(route)
    odo = LidarOdometry(OdometryConfig(object_near=object_near), initial_pose=route.pose_at(0.0))
    errors = []
    scans = simulate_scans(world, LIDAR_PRESETS["utm30lx"], route, seed=0, obstacles=people)
    for scan, true in scans:
        if scan.stamp > until:
            break
        odo.update(scan)
        errors.append(float(np.hypot(*(odo.pose[:2] - true[:2]))))
    return max(errors), errors[-1]


@pytest.mark.parametrize("near", [1.0, 0.0])
def test_a_person_walking_up_beside_the_robot_is_not_followed(near):
    """At 90.4 s the third person appears 0.1 m from the scanner and walks on ahead of the
    robot along a corridor the scan leaves otherwise free (conditioning 0.002). Fused at
    first sight and found to move only 0.3 s later, they fixed the pose along it, and the
    odometry followed them 1.6 m back; the second one, at 52 s, 2.9 m. Not fused where they
    appear within ``object_near`` of the scanner, the pose falls 0.28 m behind at worst
    while they fill the view ahead, and is back within centimetres once they walk on."""
    worst, last = _tour_with_people_on_its_own_route(near, 100.0)
    if near:
        assert worst < 0.5 and last < 0.1
    else:
        assert worst > 1.0 and last > 1.0


def test_object_settings_out_of_range_are_refused():
    """Negative sizes or a reach shorter than the stillness threshold are named errors."""
    for bad in ({"object_size": -0.1}, {"object_lag": -1.0}, {"object_reach": 0.05},
                {"object_near": -1.0}):  # fmt: skip
        with pytest.raises(ValueError, match="object_"):
            OdometryConfig(**bad)
