"""The simulator: worlds of wall segments, LiDAR models, robot routes and simulated scans.

Reproduces the paper's Sec. IV-A scenario (a maze driven for 600 s, scanned by a Hokuyo
UTM-30LX), adds worlds that repeat themselves (a warehouse of identical aisles, identical rooms
off a corridor, a hall of pillars), routes that are hard on SLAM, and lets users simulate their
own floor plans from map_server maps.

Names are imported on first use, so that a command which only needs a LiDAR preset or a world
name does not load Numba and SciPy.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bioslam.sim.adversarial import ROUTES, AdversarialConfig, make_adversarial_route
    from bioslam.sim.hall import hall_world
    from bioslam.sim.lidar import LIDAR_PRESETS, LidarModel
    from bioslam.sim.mapworld import MapWorldConfig, world_from_map, world_from_occupancy
    from bioslam.sim.maze import maze_world
    from bioslam.sim.rooms import rooms_world
    from bioslam.sim.route import Route, RouteConfig, make_route
    from bioslam.sim.simulate import (
        MovingObstacle,
        people_on_roadmap,
        people_on_route,
        scan_stamps,
        scanner_trajectory,
        simulate_scans,
        true_ranges,
    )
    from bioslam.sim.warehouse import warehouse_world
    from bioslam.sim.world import Roadmap, World
    from bioslam.sim.worlds import WORLDS, load_world

#: Public name -> the module of the simulator that defines it.
_WHERE = {
    "ROUTES": "adversarial",
    "AdversarialConfig": "adversarial",
    "make_adversarial_route": "adversarial",
    "hall_world": "hall",
    "LIDAR_PRESETS": "lidar",
    "LidarModel": "lidar",
    "MapWorldConfig": "mapworld",
    "world_from_map": "mapworld",
    "world_from_occupancy": "mapworld",
    "maze_world": "maze",
    "rooms_world": "rooms",
    "Route": "route",
    "RouteConfig": "route",
    "make_route": "route",
    "MovingObstacle": "simulate",
    "people_on_roadmap": "simulate",
    "people_on_route": "simulate",
    "scan_stamps": "simulate",
    "scanner_trajectory": "simulate",
    "simulate_scans": "simulate",
    "true_ranges": "simulate",
    "warehouse_world": "warehouse",
    "Roadmap": "world",
    "World": "world",
    "WORLDS": "worlds",
    "load_world": "worlds",
}

__all__ = [
    "LIDAR_PRESETS",
    "ROUTES",
    "WORLDS",
    "AdversarialConfig",
    "LidarModel",
    "MapWorldConfig",
    "MovingObstacle",
    "Roadmap",
    "Route",
    "RouteConfig",
    "World",
    "hall_world",
    "load_world",
    "make_adversarial_route",
    "make_route",
    "maze_world",
    "people_on_roadmap",
    "people_on_route",
    "rooms_world",
    "scan_stamps",
    "scanner_trajectory",
    "simulate_scans",
    "true_ranges",
    "warehouse_world",
    "world_from_map",
    "world_from_occupancy",
]


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"bioslam.sim.{_WHERE[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE])
