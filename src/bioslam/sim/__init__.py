"""The simulator: worlds of wall segments, LiDAR models, robot routes and simulated scans.

Reproduces the paper's Sec. IV-A scenario (a maze driven for 600 s, scanned by a Hokuyo
UTM-30LX), adds worlds that repeat themselves (a warehouse of identical aisles, identical rooms
off a corridor, a hall of pillars), routes that are hard on SLAM, and lets users simulate their
own floor plans from map_server maps.
"""

from bioslam.sim.adversarial import AdversarialConfig, make_adversarial_route
from bioslam.sim.hall import hall_world
from bioslam.sim.lidar import LIDAR_PRESETS, LidarModel
from bioslam.sim.mapworld import MapWorldConfig, world_from_map, world_from_occupancy
from bioslam.sim.maze import maze_world
from bioslam.sim.rooms import rooms_world
from bioslam.sim.route import Route, RouteConfig, make_route
from bioslam.sim.simulate import (
    MovingObstacle,
    people_on_roadmap,
    scan_stamps,
    simulate_scans,
    true_ranges,
)
from bioslam.sim.warehouse import warehouse_world
from bioslam.sim.world import Roadmap, World
from bioslam.sim.worlds import WORLDS, load_world

#: Route generators by name (``bioslam sim --route``): each takes ``(world, duration, seed,
#: config)``.
ROUTES = {"tour": make_route, "adversarial": make_adversarial_route}

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
    "rooms_world",
    "scan_stamps",
    "simulate_scans",
    "true_ranges",
    "warehouse_world",
    "world_from_map",
    "world_from_occupancy",
]
