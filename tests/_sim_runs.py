"""The odometry on a simulated route, started where a test says: on the world's frame, off it,
or at the origin as ``bioslam run`` starts it (where the walls fall in the map's cells)."""

import itertools

import numpy as np

from bioslam.geometry import between, compose
from bioslam.odometry import LidarOdometry


def odometry_run(
    world_name, route_name, lidar, seed, duration, start=None, offset=(0, 0, 0), config=None,
    thin=None, every=1, until=None,
):
    """(estimate, truth): the odometry's poses, moved onto the true start where it started
    elsewhere, and the true poses. ``start`` "origin" starts the odometry at the origin;
    otherwise at the true first pose plus ``offset`` (x, y, theta). ``thin`` (metres,
    radians or None) keeps a scan per distance or angle along the true path
    (:func:`bioslam.thinning.thin_indices`); ``every`` keeps every n-th scan (a log thinned
    by count); ``until`` (seconds) stops the route's scans there, the route itself planned for
    ``duration``. ``world_name``: a built-in world or a map YAML's path. ``lidar``: a preset's
    name or a :class:`~bioslam.sim.LidarModel`."""
    from bioslam.sim import LIDAR_PRESETS, ROUTES, load_world, simulate_scans
    from bioslam.thinning import thin_indices

    world = load_world(world_name)
    route = ROUTES[route_name](world, duration=duration, seed=seed)
    model = LIDAR_PRESETS[lidar] if isinstance(lidar, str) else lidar
    scans = simulate_scans(world, model, route, seed=seed)
    if until is not None:
        scans = itertools.takewhile(lambda item: item[0].stamp <= until, scans)
    items = list(scans)[::every]
    if thin is not None:
        items = [items[k] for k in thin_indices(np.array([t for _, t in items]), *thin)]
    truth = np.array([pose for _, pose in items])
    moved = start == "origin" or np.any(offset)
    initial = np.zeros(3) if start == "origin" else truth[0] + np.asarray(offset, dtype=float)
    odo = LidarOdometry(config, initial_pose=initial)
    estimate = []
    for scan, _ in items:
        odo.update(scan)
        estimate.append(odo.pose.copy())
    estimate = np.array(estimate)
    return (compose(truth[0], between(estimate[0], estimate)) if moved else estimate), truth


def largest_error(estimate, truth):
    """The largest position error (m)."""
    return float(np.hypot(*(estimate[:, :2] - truth[:, :2]).T).max())


def largest_step_error(estimate, truth):
    """The largest position error (m) of one step against the true step."""
    miss = between(between(truth[:-1], truth[1:]), between(estimate[:-1], estimate[1:]))
    return float(np.hypot(miss[:, 0], miss[:, 1]).max())
