"""A wall's two faces: an endpoint draws on the map's cells only where their surface faces the
way its own does, so that a scan seeing the far side of a thin wall (through a door, a 240°
scanner looking back) is not pulled onto the side the map saw."""

import numpy as np
from _scan_world import box, make_scan

from bioslam.geometry import between
from bioslam.matching.gauss_newton import (
    facing_normals,
    match_scan_to_map,
    matched_normals,
    points_per_level,
)
from bioslam.occupancy_grid import (
    MapPyramid,
    OccupancyGrid,
    subcell_point,
    subsample_by_spacing,
    thinned_normals,
)

# a room split by a partition 0.2 m thick with a 1.2 m door in it
PARTITIONED = np.array(
    box(-6, -4, 6, 4) + box(-0.1, -4, 0.1, -0.6) + box(-0.1, 0.6, 0.1, 4), dtype=float
)


def test_an_endpoint_draws_nothing_from_a_surface_facing_the_other_way():
    grid = OccupancyGrid(0.05, 4.0)
    wall = np.column_stack([np.full(41, 1.0), np.linspace(-1.0, 1.0, 41)])
    for _ in range(3):
        grid.insert_scan((0.0, 0.0, 0.0), wall, normals=np.tile([-1.0, 0.0], (41, 1)))
    ox, oy = grid.origin

    def value(fx: float, fy: float) -> float:
        args = (grid.means, grid.weights, ox, oy, grid.resolution, grid.resolution)
        return subcell_point(*args, 1.0, 0.0, fx, fy)[0]

    seen = value(0.0, 0.0)
    assert seen > 0.3
    assert value(-1.0, 0.0) == seen  # the same face
    assert value(0.0, 1.0) == seen  # across: a corner's or an edge's points
    assert value(1.0, 0.0) == 0.0  # the other face


def _match(facing: bool, start: np.ndarray, pyramid: MapPyramid, points: np.ndarray):
    levels = points_per_level(points, 0.05, 3, subsample_by_spacing(points, 0.05))
    normals = matched_normals(levels)
    faces = facing_normals(levels, normals) if facing else None
    return match_scan_to_map(
        pyramid, levels, start, (10, 10, 15), 0.05, 3.0, 0.01, 1.0, normals, facing=faces
    )[0]


def test_a_scan_of_a_walls_unseen_face_is_not_drawn_onto_the_face_the_map_saw():
    """The map saw the partition from the right only; a scan from 0.6 m left of it sees its
    left face, 0.2 m from the right one, and the right room through the door. From starts
    6-14 cm off towards the partition, the left face's endpoints fall inside the wall; drawn
    on the right face they held the pose 10 cm off from half of the starts."""
    rng = np.random.default_rng(0)
    pyramid = MapPyramid(0.05, 16.0, 3)
    for pose in [(2.0, 0.0, np.pi), (2.5, 1.5, np.pi - 0.2), (2.5, -1.5, np.pi + 0.2), (4, 0, 0)]:
        pts = make_scan(PARTITIONED, pose, sigma=0.01, rng=rng).endpoints()
        pyramid.insert_scan(pose, pts, normals=thinned_normals(pts))
    true = np.array([-0.7, 0.1, 0.05])
    points = make_scan(PARTITIONED, true, sigma=0.01, rng=rng).endpoints()
    starts = [true + np.array([dx, dy, 0.0]) for dx in (0.06, 0.1, 0.14) for dy in (-0.05, 0.05)]
    misses = {
        facing: [np.hypot(*between(true, _match(facing, s, pyramid, points))[:2]) for s in starts]
        for facing in (False, True)
    }
    assert max(misses[True]) < 0.02, misses[True]
    assert max(misses[False]) > 0.08, misses[False]  # what the faces prevent
