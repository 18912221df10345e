"""The channels a recording or live view carries: topic, schema and what it shows.

Kept free of the optional dependencies so that the layout, the tests and the docs can name the
channels without importing the Foxglove SDK.
"""

from __future__ import annotations

from typing import NamedTuple

#: Frames of the transform tree (REP 105 names): the SLAM map, the odometry's frame, the robot.
MAP_FRAME = "map"
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"

SCAN = "/scan"
TF = "/tf"
ODOMETRY_POSE = "/odometry/pose"
SLAM_POSE = "/slam/pose"
ODOMETRY_MATCH = "/odometry/match"
MAP = "/map"
COGNITIVE_MAP = "/cognitive_map"
VIEW = "/view_cells/active"
BOUNDARY_CELLS = "/boundary_cells/activity"
POSE_CELLS_XY = "/pose_cells/xy"
POSE_CELLS_THETA = "/pose_cells/theta"
POSE_CELLS_STATE = "/pose_cells/state"
LOG = "/log"

#: JSON messages carry this schema name (their JSON schema is in :mod:`.messages`).
JSON = "json"


class Topic(NamedTuple):
    """One channel: its topic, schema name (``foxglove.*`` are Foxglove's well-known protobuf
    schemas), and whether the odometry-only mode has it."""

    topic: str
    schema: str
    odometry_only: bool
    what: str


TOPICS: tuple[Topic, ...] = (
    Topic(SCAN, "foxglove.LaserScan", True, "every scan, in base_link"),
    Topic(TF, "foxglove.FrameTransforms", True,
          "odom -> base_link at every scan, map -> odom at 10 Hz"),
    Topic(ODOMETRY_POSE, "foxglove.PoseInFrame", True, "LiDAR odometry pose, in odom (10 Hz)"),
    Topic(SLAM_POSE, "foxglove.PoseInFrame", True, "SLAM pose, in map (10 Hz)"),
    Topic(ODOMETRY_MATCH, "bioslam.OdometryMatch", True, "scan-match quality (throttled)"),
    Topic(MAP, "foxglove.Grid", True, "occupancy map as built, RGBA cells (throttled)"),
    Topic(COGNITIVE_MAP, "foxglove.SceneUpdate", False,
          "experiences, odometry links, loop-closure links, trajectory (throttled)"),
    Topic(VIEW, "bioslam.ActiveView", False, "active view id, its activity V, the map event"),
    Topic(BOUNDARY_CELLS, "foxglove.RawImage", False,
          "boundary-cell activity B around the robot, forward up (throttled)"),
    Topic(POSE_CELLS_XY, "foxglove.RawImage", False,
          "pose-cell activity, maximum over heading (throttled)"),
    Topic(POSE_CELLS_THETA, "foxglove.RawImage", False,
          "pose-cell activity summed over x and y, one column per heading cell (throttled)"),
    Topic(POSE_CELLS_STATE, "bioslam.PoseCellState", False,
          "packet centre, active cells, collapses (throttled)"),
    Topic(LOG, "foxglove.Log", True,
          "odometry recoveries, loop closures accepted and rejected, pose-cell collapses"),
)


def topics_for(odometry_only: bool) -> tuple[Topic, ...]:
    """The channels a run in the given mode carries."""
    return tuple(t for t in TOPICS if t.odometry_only or not odometry_only)
