"""The simulator: worlds of wall segments, LiDAR models, robot routes and simulated scans.

Reproduces the paper's Sec. IV-A scenario (a maze driven for 600 s, scanned by a Hokuyo
UTM-30LX) and lets users simulate their own floor plans from map_server maps.
"""

from bioslam.sim.lidar import LIDAR_PRESETS, LidarModel
from bioslam.sim.mapworld import MapWorldConfig, world_from_map, world_from_occupancy
from bioslam.sim.maze import maze_world
from bioslam.sim.route import Route, RouteConfig, make_route
from bioslam.sim.simulate import (
    MovingObstacle,
    people_on_roadmap,
    scan_stamps,
    simulate_scans,
    true_ranges,
)
from bioslam.sim.world import Roadmap, World

__all__ = [
    "LIDAR_PRESETS",
    "LidarModel",
    "MapWorldConfig",
    "MovingObstacle",
    "Roadmap",
    "Route",
    "RouteConfig",
    "World",
    "make_route",
    "maze_world",
    "people_on_roadmap",
    "scan_stamps",
    "simulate_scans",
    "true_ranges",
    "world_from_map",
    "world_from_occupancy",
]
