"""The Foxglove layout that shows a recording or live view: built with the SDK's layout types,
written to ``docs/foxglove/bioslam_layout.json`` (import it in Foxglove: Layouts > Import).

Left: the 3D view in the map frame (occupancy map, cognitive map, scan, frames), following the
robot. Right, top to bottom: the boundary cells around the robot and the pose-cell packet
(x'-y' and heading), the active view id and its activity, the odometry's match score, and the
log messages.

    python -m bioslam.recording.layout [OUT.json]     # regenerate the file
"""

from __future__ import annotations

import argparse
from pathlib import Path

import foxglove.layouts as fl

from bioslam.recording import topics as tp

LAYOUT_FILE = Path(__file__).resolve().parents[3] / "docs" / "foxglove" / "bioslam_layout.json"


def _three_d() -> fl.ThreeDeePanel:
    return fl.ThreeDeePanel(
        title="map, cognitive map and scan",
        config=fl.ThreeDeeConfig(
            follow_tf=tp.BASE_FRAME,
            fixed_frame=tp.MAP_FRAME,
            follow_mode="follow-position",
            camera_state=fl.ThreeDeeCameraState(perspective=False, distance=25.0),
            topics={
                tp.MAP: fl.BaseRendererGridTopicSettings(
                    visible=True, color_mode="rgba-fields", frame_locked=True,
                ),
                tp.COGNITIVE_MAP: fl.BaseRendererSceneUpdateTopicSettings(visible=True),
                tp.SCAN: fl.BaseRendererLaserScanTopicSettings(
                    visible=True, point_size=3.0, color_mode="flat", flat_color="#e6194bff",
                ),
                tp.SLAM_POSE: fl.BaseRendererPoseTopicSettings(visible=False),
                tp.ODOMETRY_POSE: fl.BaseRendererPoseTopicSettings(visible=False),
            },
        ),
    )  # fmt: skip


def _image(topic: str, title: str) -> fl.ImagePanel:
    return fl.ImagePanel(
        title=title, config=fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic=topic))
    )


def _plot(title: str, series: list[tuple[str, str]]) -> fl.PlotPanel:
    return fl.PlotPanel(
        title=title,
        config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=path, label=label) for path, label in series],
            show_legend=True,
        ),
    )


def _column(*panels: tuple[float, fl.BasePanel]) -> fl.SplitContainer:
    return fl.SplitContainer(
        direction="column",
        items=[fl.SplitItem(proportion=p, content=panel) for p, panel in panels],
    )


def build_layout() -> fl.Layout:
    """The layout for every channel of :mod:`.topics`."""
    neurons = fl.SplitContainer(
        direction="row",
        items=[
            fl.SplitItem(content=_image(tp.BOUNDARY_CELLS, "boundary cells (forward up)")),
            fl.SplitItem(content=_column(
                (3.0, _image(tp.POSE_CELLS_XY, "pose cells x'-y' (max over heading)")),
                (1.0, _image(tp.POSE_CELLS_THETA, "pose cells heading")),
            )),
        ],
    )  # fmt: skip
    side = _column(
        (2.0, neurons),
        (1.0, _plot("active view", [
            (f"{tp.VIEW}.view_id", "view id"),
            (f"{tp.VIEW}.experience", "experience"),
        ])),
        (1.0, _plot("view activity V and odometry match score", [
            (f"{tp.VIEW}.activity", "V of the active view"),
            (f"{tp.ODOMETRY_MATCH}.score", "odometry match score"),
        ])),
        (1.2, fl.LogPanel(title="events", config=fl.LogConfig(topic_to_render=tp.LOG))),
    )  # fmt: skip
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=3.0, content=_three_d()),
                fl.SplitItem(proportion=2.0, content=side),
            ],
        )
    )


def layout_json() -> str:
    """The layout file's text (indented, so that changes read well in a diff)."""
    import json

    return json.dumps(json.loads(build_layout().to_json()), indent=2) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Write the Foxglove layout for bioslam.")
    parser.add_argument("out", type=Path, nargs="?", default=LAYOUT_FILE)
    args = parser.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(layout_json())
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
