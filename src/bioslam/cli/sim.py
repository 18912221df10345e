"""``bioslam sim``: simulate a LiDAR driving through a world; write a ROS 2 bag, ground truth
(TUM) and a picture of the world with the route."""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bioslam.sim.lidar import LIDAR_PRESETS
from bioslam.sim.worlds import WORLDS

if TYPE_CHECKING:
    from bioslam.sim import MovingObstacle, Route, World

#: ``--route`` names (``bioslam.sim.ROUTES``; named here so that ``--help`` loads no Numba).
ROUTE_NAMES = ("tour", "adversarial", "reversing")
#: ``--storage`` names (``bioslam.io.bag_writer.STORAGES``; likewise without loading rosbags).
STORAGE_NAMES = ("sqlite3", "mcap")
BAG_NAME = "scans"
GT_NAME = "gt.tum"
FIGURE_NAME = "world.png"
SCAN_TOPIC = "/scan"
GT_TOPIC = "/ground_truth"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "sim",
        help="simulate LiDAR scans along a route through a built-in world or your own map",
        description="Drive a simulated robot with a 2D LiDAR through a world and write "
        f"OUT/{BAG_NAME}/ (ROS 2 bag, {SCAN_TOPIC} sensor_msgs/LaserScan and {GT_TOPIC} "
        f"geometry_msgs/PoseStamped), OUT/{GT_NAME} (ground truth at every scan stamp) and "
        f"OUT/{FIGURE_NAME}.",
    )
    p.add_argument(
        "--world",
        default="maze",
        help=f"a built-in world ({', '.join(WORLDS)}) or a map_server map YAML (default: maze)",
    )
    p.add_argument(
        "--route",
        choices=ROUTE_NAMES,
        default="tour",
        help="'tour': along the corridor centre-lines (default); 'adversarial': weaving up to "
        "0.5 m off centre, turning back part way, spinning on the spot, then driving fast; "
        "'reversing': the tour, backing up 12 s along its own path every 45 s",
    )
    p.add_argument("--lidar", choices=sorted(LIDAR_PRESETS), default="utm30lx", help="LiDAR preset")
    p.add_argument("--duration", type=float, default=600.0, help="seconds (default 600)")
    p.add_argument("--seed", type=int, default=0, help="route and noise seed (default 0)")
    p.add_argument("--noise", type=float, help="range noise sigma in metres (preset default)")
    p.add_argument("--dropout", type=float, help="probability a beam returns nothing (NaN)")
    p.add_argument("--no-sweep", action="store_true", help="cast all beams of a scan from one pose")
    p.add_argument(
        "--mount-yaw",
        type=float,
        default=0.0,
        help="the scanner's heading on the robot, degrees from its forward axis (180: facing "
        "backwards); the ground truth is the scanner's pose",
    )
    p.add_argument(
        "--clockwise",
        action="store_true",
        help="the scanner sweeps clockwise: its angles count down (a negative angle_increment)",
    )
    p.add_argument(
        "--no-return-as-max",
        action="store_true",
        help="report a beam that met nothing as range_max instead of +inf (as loggers and "
        "drivers that do not follow REP 117 do)",
    )
    p.add_argument("--max-speed", type=float, help="m/s (default 0.5)")
    p.add_argument("--max-yaw-rate", type=float, help="rad/s (default 0.8)")
    p.add_argument(
        "--fast-turns", action="store_true", help="take corners at 1 rad/s (odometry stress)"
    )
    p.add_argument(
        "--lateral-offset",
        type=float,
        help="adversarial route: largest offset from the centre-lines, metres (default 0.5)",
    )
    p.add_argument(
        "--turn-back-every",
        type=float,
        help="adversarial route: mean distance between turn-backs, metres (default 40)",
    )
    p.add_argument("--people", type=int, default=0, help="people walking the corridors (default 0)")
    p.add_argument("--storage", choices=STORAGE_NAMES, default="sqlite3", help="bag storage")
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--force", action="store_true", help=f"replace an existing OUT/{BAG_NAME}")
    p.set_defaults(func=run)


def _prepare_bag_dir(bag: Path, force: bool) -> None:
    if not bag.exists():
        return
    if not force:
        raise ValueError(f"{bag} already exists; pass --force to replace it")
    if not (bag / "metadata.yaml").is_file():
        raise ValueError(f"{bag} exists and is not a ROS 2 bag; not replacing it")
    shutil.rmtree(bag)


def save_world_figure(
    path: Path, world: World, route: Route, people: Sequence[MovingObstacle] = ()
) -> None:
    """The walls in black, the route coloured by time, the start marked, people's beats."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    xy = route.pose_at(np.linspace(0.0, route.duration, max(2, int(route.duration * 10))))[:, :2]
    fig, ax = plt.subplots(figsize=(8, 6.5), layout="constrained")
    walls = world.segments.reshape(-1, 2, 2)
    ax.add_collection(LineCollection(walls, colors="black", linewidths=1.2))
    path_lines = LineCollection(np.stack([xy[:-1], xy[1:]], axis=1), cmap="viridis", linewidths=1)
    path_lines.set_array(np.linspace(0.0, route.duration, len(xy) - 1))
    ax.add_collection(path_lines)
    ax.plot(*xy[0], "o", color="tab:red", label="start")
    for k, person in enumerate(people):
        ends = np.array([person.start, person.end])
        ax.plot(
            *ends.T, "-", color="tab:orange", lw=3, alpha=0.7, label="people" if k == 0 else None
        )
    fig.colorbar(path_lines, ax=ax, label="time (s)", shrink=0.8)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{world.name}: {route.path_length():.0f} m in {route.duration:.0f} s")
    ax.legend(loc="upper right")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _make_route(world: World, args: argparse.Namespace) -> Route:
    from dataclasses import replace

    from bioslam.sim import ROUTES, RouteConfig

    limits = {
        "max_speed": args.max_speed,
        "max_yaw_rate": args.max_yaw_rate,
        "fast_turns": args.fast_turns or None,
    }
    given = {k: v for k, v in limits.items() if v is not None}
    if args.route in ("tour", "reversing"):
        if args.lateral_offset is not None or args.turn_back_every is not None:
            raise ValueError("--lateral-offset and --turn-back-every need --route adversarial")
        config = replace(RouteConfig(), **given)
        return ROUTES[args.route](world, duration=args.duration, seed=args.seed, config=config)

    from bioslam.sim.adversarial import AdversarialConfig

    adv = AdversarialConfig()
    weave = {"lateral_offset": args.lateral_offset, "turn_back_every": args.turn_back_every}
    adv = replace(adv, route=replace(adv.route, **given),
                  **{k: v for k, v in weave.items() if v is not None})
    return ROUTES[args.route](world, duration=args.duration, seed=args.seed, config=adv)


def run(args: argparse.Namespace) -> dict:
    from dataclasses import replace

    from tqdm import tqdm

    from bioslam.io.bag_writer import ScanBagWriter
    from bioslam.io.tum import write_tum
    from bioslam.sim import (
        load_world,
        people_on_roadmap,
        scan_stamps,
        scanner_trajectory,
        simulate_scans,
    )

    started = time.perf_counter()
    world = load_world(args.world)
    lidar = LIDAR_PRESETS[args.lidar]
    changes = {
        "sweep": not args.no_sweep,
        "mount_yaw": math.radians(args.mount_yaw),
        "clockwise": args.clockwise,
        "no_return_as_max": args.no_return_as_max,
    }
    if args.noise is not None:
        changes["noise_sigma"] = args.noise
    if args.dropout is not None:
        changes["dropout_prob"] = args.dropout
    lidar = replace(lidar, **changes)
    route = _make_route(world, args)
    out: Path = args.out
    bag = out / BAG_NAME
    _prepare_bag_dir(bag, args.force)
    out.mkdir(parents=True, exist_ok=True)
    stamps = scan_stamps(lidar, route)
    people = people_on_roadmap(world, args.people, seed=args.seed) if args.people else []
    scans = simulate_scans(world, lidar, route, seed=args.seed, obstacles=people)
    writer = ScanBagWriter(
        bag, SCAN_TOPIC, scan_time=lidar.scan_time, storage=args.storage, pose_topic=GT_TOPIC
    )
    with writer, tqdm(total=stamps.size, unit="scan", file=sys.stderr, mininterval=0.5) as bar:
        for scan, pose in scans:
            writer.write(scan)
            writer.write_pose(scan.stamp, pose)
            bar.update()
    write_tum(out / GT_NAME, scanner_trajectory(lidar, route, stamps))
    save_world_figure(out / FIGURE_NAME, world, route, people)
    return {
        "world": world.name,
        "route": args.route,
        "lidar": lidar.name,
        "mount_yaw_deg": args.mount_yaw,
        "clockwise": args.clockwise,
        "scans": writer.count,
        "beams": lidar.beams,
        "duration_s": round(float(route.duration), 3),
        "path_length_m": round(route.path_length(), 3),
        "seed": args.seed,
        "people": len(people),
        "bag": str(bag),
        "gt": str(out / GT_NAME),
        "figure": str(out / FIGURE_NAME),
        "wall_s": round(time.perf_counter() - started, 2),
    }
