"""bioslam's state as Foxglove messages (the SDK's well-known schemas, or JSON with a schema).

Pure conversions: each function takes arrays and numbers and returns a message; what is sent
when is :mod:`.recorder`'s business. Poses are planar ``(x, y, theta)``; z is 0 except for the
cognitive map, drawn a little above the occupancy map so that it stays visible.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from functools import cache

import foxglove
import numpy as np
from foxglove.messages import (
    Color,
    FrameTransform,
    FrameTransforms,
    Grid,
    LaserScan,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    PackedElementField,
    PackedElementFieldNumericType,
    Point3,
    Pose,
    PoseInFrame,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector2,
    Vector3,
)
from numpy.typing import NDArray

from bioslam.geometry import compose, inverse
from bioslam.recording.topics import BASE_FRAME, MAP_FRAME, ODOM_FRAME
from bioslam.scan import returns

FloatArray = NDArray[np.float64]

#: Height of the cognitive map above the occupancy grid, metres.
SCENE_Z = 0.05
_IDENTITY = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def timestamp(ns: int) -> Timestamp:
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def quaternion(theta: float) -> Quaternion:
    """The rotation by ``theta`` about z."""
    half = 0.5 * theta
    return Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))


def planar_pose(pose: Sequence[float], z: float = 0.0) -> Pose:
    x, y, theta = (float(v) for v in pose[:3])
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=quaternion(theta))


def laser_scan(
    ns: int, ranges: NDArray[np.floating], start_angle: float, end_angle: float
) -> LaserScan:
    """A scan in the robot frame; beams without a return are NaN (the viewers skip them).

    Ranges are sent as float32 values (what sensors measure, and a double holding a float32
    value compresses to about half)."""
    return LaserScan(
        timestamp=timestamp(ns),
        frame_id=BASE_FRAME,
        pose=Pose(position=Vector3(), orientation=_IDENTITY),
        start_angle=float(start_angle),
        end_angle=float(end_angle),
        ranges=np.asarray(ranges, dtype=np.float32).tolist(),
    )


def scan_ranges(
    ranges: NDArray[np.floating], range_min: float, range_max: float
) -> NDArray[np.float32]:
    """The ranges with every beam outside ``[range_min, range_max)`` (no return, REP 117
    codes, NaN, a beam reported at the maximum) set to NaN, which viewers leave out; zero is
    never a return."""
    valid = returns(ranges, range_min, range_max)
    return np.where(valid, ranges, np.float32(np.nan)).astype(np.float32, copy=False)


def map_to_odom(slam_pose: Sequence[float], odometry_pose: Sequence[float]) -> FloatArray:
    """The transform ``map -> odom`` that places the odometry's robot pose at the SLAM pose:
    ``slam = (map->odom) ⊕ odometry``."""
    return compose(np.asarray(slam_pose, dtype=np.float64), inverse(odometry_pose))


def _transform(
    stamp: Timestamp, parent: str, child: str, x: float, y: float, theta: float
) -> FrameTransform:
    return FrameTransform(
        timestamp=stamp,
        parent_frame_id=parent,
        child_frame_id=child,
        translation=Vector3(x=x, y=y, z=0.0),
        rotation=quaternion(theta),
    )


def odometry_transform(ns: int, odometry_pose: Sequence[float]) -> FrameTransforms:
    """``odom -> base_link``: the odometry's pose (sent with every scan)."""
    x, y, theta = (float(v) for v in odometry_pose[:3])
    return FrameTransforms(
        transforms=[_transform(timestamp(ns), ODOM_FRAME, BASE_FRAME, x, y, theta)]
    )


def correction_transform(
    ns: int, slam_pose: Sequence[float], odometry_pose: Sequence[float]
) -> FrameTransforms:
    """``map -> odom``: the SLAM correction (:func:`map_to_odom`, here in plain floats). It
    changes slowly, at loop closures, so it may go out less often than the scans (viewers
    interpolate between transforms, as for a SLAM node's ``map -> odom``)."""
    sx, sy, st = (float(v) for v in slam_pose[:3])
    ox, oy, ot = (float(v) for v in odometry_pose[:3])
    theta = st - ot
    c, s = math.cos(theta), math.sin(theta)
    x, y = sx - (c * ox - s * oy), sy - (s * ox + c * oy)
    return FrameTransforms(
        transforms=[_transform(timestamp(ns), MAP_FRAME, ODOM_FRAME, x, y, theta)]
    )


def pose_in_frame(ns: int, frame: str, pose: Sequence[float]) -> PoseInFrame:
    return PoseInFrame(timestamp=timestamp(ns), frame_id=frame, pose=planar_pose(pose))


#: log-odds are quantised to this many levels per unit for the grey lookup table
_LEVELS_PER_LOGODD = 16.0


@cache
def _occupancy_table() -> NDArray[np.uint8]:
    """RGBA for each quantised log-odds (index 0-254, 127 = 0.5) and for unknown (255)."""
    logodds = (np.arange(255) - 127) / _LEVELS_PER_LOGODD
    grey = np.rint(255.0 / (1.0 + np.exp(logodds))).astype(np.uint8)  # 1 - p
    table = np.zeros((256, 4), dtype=np.uint8)
    table[:255, :3] = grey[:, None]
    table[:255, 3] = 255
    return table


def occupancy_rgba(logodds: NDArray[np.floating], known: NDArray[np.bool_]) -> bytes:
    """Grid cells as RGBA bytes: free white, occupied black, unknown transparent (the way a
    map is usually drawn, with nothing to configure in the viewer). The grey level resolves
    log-odds to 1/16 (probability to better than 1 %)."""
    index = np.clip(np.rint(logodds * _LEVELS_PER_LOGODD) + 127, 0, 254).astype(np.uint8)
    index[~known] = 255
    return _occupancy_table()[index].tobytes()


@cache
def _rgba_fields() -> list[PackedElementField]:
    kind = PackedElementFieldNumericType.Uint8
    return [
        PackedElementField(name=name, offset=i, type=kind)
        for i, name in enumerate(("red", "green", "blue", "alpha"))
    ]


def occupancy_grid(
    ns: int,
    logodds: NDArray[np.floating],
    known: NDArray[np.bool_],
    origin: Sequence[float],
    resolution: float,
) -> Grid:
    """An occupancy map in the map frame; row 0 is the lowest y, as in
    :class:`bioslam.occupancy_grid.OccupancyGrid`."""
    cols = logodds.shape[1]
    return Grid(
        timestamp=timestamp(ns),
        frame_id=MAP_FRAME,
        pose=planar_pose((origin[0], origin[1], 0.0)),
        column_count=cols,
        cell_size=Vector2(x=resolution, y=resolution),
        row_stride=4 * cols,
        cell_stride=4,
        fields=_rgba_fields(),
        data=occupancy_rgba(logodds, known),
    )


def _colour(rgba: Sequence[float]) -> Color:
    r, g, b, a = rgba
    return Color(r=r, g=g, b=b, a=a)


EXPERIENCE_COLOUR = (0.12, 0.47, 0.71, 1.0)
CURRENT_COLOUR = (1.0, 0.5, 0.05, 1.0)
ODOMETRY_LINK_COLOUR = (0.45, 0.45, 0.45, 1.0)
LOOP_LINK_COLOUR = (0.84, 0.15, 0.16, 1.0)
TRAJECTORY_COLOUR = (0.17, 0.63, 0.17, 1.0)


def _points(xy: FloatArray, z: float) -> list[Point3]:
    return [Point3(x=x, y=y, z=z) for x, y in xy.tolist()]


def _line_list(segments: FloatArray, colour: Sequence[float], thickness: float) -> LinePrimitive:
    """Segments ``(K, 2, 2)`` as one line list (pairs of points)."""
    return LinePrimitive(
        type=LinePrimitiveLineType.LineList,
        pose=Pose(position=Vector3(), orientation=_IDENTITY),
        thickness=thickness,
        scale_invariant=True,
        points=_points(segments.reshape(-1, 2), SCENE_Z),
        color=_colour(colour),
    )


def cognitive_map_scene(
    ns: int,
    poses: FloatArray,
    links: NDArray[np.int64],
    loop: NDArray[np.bool_],
    current: int,
    trajectory: FloatArray | None = None,
    node_size: float = 0.08,
) -> SceneUpdate:
    """The cognitive map (Eq. 12-13) in the map frame: experiences as spheres (the current
    one larger, orange), odometry links grey, loop-closure links red and thicker, and
    optionally a trajectory (``(N, 2)`` positions) as a green line.

    ``links`` is ``(E, 2)`` source/target experience ids, ``loop`` marks the loop closures.
    Each entity replaces its previous version (same id), so the last message is the map."""
    size = Vector3(x=node_size, y=node_size, z=node_size)
    colour = _colour(EXPERIENCE_COLOUR)
    spheres = [
        SpherePrimitive(
            pose=Pose(position=Vector3(x=x, y=y, z=SCENE_Z), orientation=_IDENTITY),
            size=size,
            color=colour,
        )
        for x, y in poses[:, :2].tolist()
    ]
    if 0 <= current < len(poses):
        big = 2.5 * node_size
        spheres.append(
            SpherePrimitive(
                pose=planar_pose(poses[current], SCENE_Z),
                size=Vector3(x=big, y=big, z=big),
                color=_colour(CURRENT_COLOUR),
            )
        )
    segments = poses[:, :2][links] if len(links) else np.zeros((0, 2, 2))
    lines = [
        _line_list(segments[~loop], ODOMETRY_LINK_COLOUR, 1.5),
        _line_list(segments[loop], LOOP_LINK_COLOUR, 3.0),
    ]
    if trajectory is not None and len(trajectory) > 1:
        lines.append(
            LinePrimitive(
                type=LinePrimitiveLineType.LineStrip,
                pose=Pose(position=Vector3(), orientation=_IDENTITY),
                thickness=1.0,
                scale_invariant=True,
                points=_points(trajectory[:, :2], SCENE_Z),
                color=_colour(TRAJECTORY_COLOUR),
            )
        )
    entity = SceneEntity(
        timestamp=timestamp(ns),
        frame_id=MAP_FRAME,
        id="cognitive_map",
        spheres=spheres,
        lines=lines,
    )
    return SceneUpdate(entities=[entity])


@cache
def colour_table(name: str = "viridis") -> NDArray[np.uint8]:
    """A matplotlib colour map as a (256, 3) RGB table, for false-colour images."""
    from matplotlib import colormaps

    return (colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3] * 255.0).astype(np.uint8)


def false_colour(ns: int, values: NDArray[np.floating], frame: str = BASE_FRAME) -> RawImage:
    """A 2-D array as an ``rgb8`` image, 0 (dark) to its maximum (bright); row 0 on top."""
    peak = float(np.max(values)) if values.size else 0.0
    scaled = values * (255.0 / peak) if peak > 0.0 else np.zeros_like(values)
    index = np.clip(scaled, 0, 255).astype(np.uint8)
    rgb = colour_table()[index]
    height, width = index.shape
    return RawImage(
        timestamp=timestamp(ns),
        frame_id=frame,
        width=width,
        height=height,
        encoding="rgb8",
        step=3 * width,
        data=np.ascontiguousarray(rgb).tobytes(),
    )


def polar_lookup(
    ring_distances: Sequence[float], cells_per_ring: int, pixels: int
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """For a ``pixels`` x ``pixels`` picture of the boundary cells around the robot (forward
    up, left to the left, the outermost ring at the border): the activity-vector index of the
    cell each pixel lies in, and which pixels lie within the rings.

    Cell ``r * cells_per_ring + k`` is ring ``r`` at angle ``2 pi k / cells_per_ring``
    (:mod:`bioslam.boundary`); a pixel takes its nearest ring and angle."""
    rings = np.asarray(ring_distances, dtype=np.float64)
    spacing = float(np.median(np.diff(rings))) if rings.size > 1 else 1.0
    outer = rings[-1] + 0.5 * spacing
    centre = (np.arange(pixels) + 0.5) / pixels * 2.0 - 1.0  # -1 .. 1
    forward = -centre[:, None] * outer  # rows: top is forward (+x)
    left = -centre[None, :] * outer  # columns: left is +y
    distance = np.hypot(forward, left)
    angle = np.mod(np.arctan2(left, forward), 2.0 * np.pi)
    ring = np.abs(distance[..., None] - rings).argmin(axis=-1)
    cell = np.rint(angle / (2.0 * np.pi) * cells_per_ring).astype(np.int64) % cells_per_ring
    inside = (distance <= outer) & (distance >= rings[0] - 0.5 * spacing)
    return ring * cells_per_ring + cell, inside


def boundary_image(
    ns: int, activity: FloatArray, lookup: NDArray[np.int64], inside: NDArray[np.bool_]
) -> RawImage:
    """The boundary-cell activity ``B`` (Eq. 5) drawn where each cell's field lies."""
    values = np.where(inside, activity[lookup], 0.0)
    return false_colour(ns, values)


def _blocks(values: FloatArray, rows: int, cols: int) -> FloatArray:
    """Each element as a ``rows`` x ``cols`` block of pixels (nearest-neighbour enlargement)."""
    return np.repeat(np.repeat(values, rows, axis=0), cols, axis=1)


def pose_cell_images(
    ns: int, xy: FloatArray, theta: FloatArray, scale: int = 3
) -> tuple[RawImage, RawImage]:
    """The pose-cell activity ``PC[x', y', θ']`` (Sec. III-C) as two pictures: ``xy``, its
    maximum over heading (``(n_x', n_y')``; drawn x' to the right, y' up), and ``theta``, its
    sum over x' and y' (``(n_θ',)``; one column per heading cell). Each cell is ``scale``
    pixels wide."""
    top_down = np.asarray(xy).T[::-1]
    strip = np.asarray(theta)[None, :]
    return (
        false_colour(ns, _blocks(top_down, scale, scale)),
        false_colour(ns, _blocks(strip, 4 * scale, scale)),
    )


def log_message(ns: int, level: str, text: str, name: str) -> Log:
    """A log line; ``level`` is one of Foxglove's levels (``Info``, ``Warning``, ...)."""
    return Log(timestamp=timestamp(ns), level=getattr(LogLevel, level), message=text, name=name)


def json_schema(name: str, properties: dict[str, str]) -> foxglove.Schema:
    """A JSON-schema for flat JSON messages, so that viewers can list and plot their fields."""
    schema = {
        "title": name,
        "type": "object",
        "properties": {key: {"type": kind} for key, kind in properties.items()},
    }
    return foxglove.Schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode())


def active_view_json(
    view_id: int, is_new: bool, activity: float, event: str, experience: int, views: int,
    experiences: int, loop_closures: int,
) -> str:
    """A ``bioslam.ActiveView`` message (:data:`ACTIVE_VIEW_FIELDS`), formatted directly: it
    goes out at every look of the view cells."""
    return (
        f'{{"view_id":{int(view_id)},"is_new":{"true" if is_new else "false"},'
        f'"activity":{_number(activity)},"event":"{event}","experience":{int(experience)},'
        f'"views":{int(views)},"experiences":{int(experiences)},'
        f'"loop_closures":{int(loop_closures)}}}'
    )  # fmt: skip


def _flag(value: bool) -> str:
    return "true" if value else "false"


def odometry_match_json(
    score: float, iterations: int, points: int, condition: float, degenerate: bool,
    recovered: bool, predicted_only: bool,
) -> str:
    """A ``bioslam.OdometryMatch`` message (:data:`ODOMETRY_MATCH_FIELDS`): the fields of the
    odometry's :class:`~bioslam.odometry.MatchReport`."""
    return (
        f'{{"score":{_number(score)},"iterations":{int(iterations)},'
        f'"points":{int(points)},"condition":{_number(condition)},'
        f'"degenerate":{_flag(degenerate)},"recovered":{_flag(recovered)},'
        f'"predicted_only":{_flag(predicted_only)}}}'
    )  # fmt: skip


def pose_cell_json(centre: Sequence[float], active_cells: int, collapses: int) -> str:
    """A ``bioslam.PoseCellState`` message (:data:`POSE_CELL_FIELDS`): the packet centre in
    cells, the active cells, the collapses so far."""
    x, y, theta = (_number(v) for v in centre[:3])
    return (
        f'{{"x":{x},"y":{y},"theta":{theta},"active_cells":{int(active_cells)},'
        f'"collapses":{int(collapses)}}}'
    )


def _number(value: float) -> str:
    """A JSON number; NaN and infinities (which JSON lacks) become null."""
    value = float(value)
    return repr(value) if math.isfinite(value) else "null"


ACTIVE_VIEW_FIELDS = {
    "view_id": "integer",
    "is_new": "boolean",
    "activity": "number",
    "event": "string",
    "experience": "integer",
    "views": "integer",
    "experiences": "integer",
    "loop_closures": "integer",
}
ODOMETRY_MATCH_FIELDS = {
    "score": "number",
    "iterations": "integer",
    "points": "integer",
    "condition": "number",
    "degenerate": "boolean",
    "recovered": "boolean",
    "predicted_only": "boolean",
}
POSE_CELL_FIELDS = {
    "x": "number",
    "y": "number",
    "theta": "number",
    "active_cells": "integer",
    "collapses": "integer",
}
