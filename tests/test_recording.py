"""Watching a run: the pipeline's per-scan observer, the MCAP recording (read back with the
``mcap`` reader) and the live Foxglove WebSocket server (a ``websockets`` client on 127.0.0.1)."""

from __future__ import annotations

import asyncio
import base64
import json
import math
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from loop_world import ring_route, ring_world

from bioslam.cli import main
from bioslam.geometry import compose
from bioslam.pipeline import RunOptions, run_slam
from bioslam.recording import topics as tp
from bioslam.sim import LIDAR_PRESETS, simulate_scans

pytest.importorskip("foxglove")
pytest.importorskip("mcap_protobuf")

from bioslam.recording.reading import (
    decoded_messages,
    format_summary,
    log_times,
    summarize,
)
from bioslam.recording.session import Session

#: where the route starts in the ring world: the map frame's origin
START = np.array([1.25, 0.75, 0.0])


@pytest.fixture(scope="module")
def ring_scans():
    """Two laps of the ring corridor: a run that makes experiences and closes loops."""
    route = ring_route(laps=2.0)
    pairs = simulate_scans(ring_world(), LIDAR_PRESETS["urg04lx"], route, seed=3)
    return [scan for scan, _ in pairs]


def _quiet() -> RunOptions:
    return RunOptions(progress=False, warm_up=False)


@pytest.fixture(scope="module")
def recorded(ring_scans, tmp_path_factory):
    """The two laps recorded: the file, the session and the run's result."""
    path = tmp_path_factory.mktemp("rec") / "ring.mcap"
    with Session(record=path, metadata={"input": "ring"}) as session:
        result = run_slam(ring_scans, options=_quiet(), observer=session.observer)
        session.finish(result.system)
    assert result.error is None
    return path, session, result


def test_observer_sees_every_scan_in_order_with_the_pose_process_returned(ring_scans):
    scans = ring_scans[:80]
    seen: list[tuple[float, np.ndarray, np.ndarray]] = []

    def observer(scan, pose, system):
        seen.append((scan.stamp, np.asarray(pose, dtype=float), system.self_motion.pose.copy()))

    result = run_slam(scans, options=_quiet(), observer=observer)
    assert [s for s, _, _ in seen] == [scan.stamp for scan in scans]
    odometry = result.system.odometry_trajectory()
    np.testing.assert_allclose(np.array([o for _, _, o in seen]), odometry.poses)
    # the last pose seen is the system's estimate at the last scan
    np.testing.assert_allclose(seen[-1][1], result.system.trajectory().poses[-1], atol=1e-9)


def test_recording_has_every_channel_with_its_schema_and_what_was_sent(recorded, ring_scans):
    path, session, _result = recorded
    info = summarize(path)
    assert info.schemas() == {t.topic: t.schema for t in tp.topics_for(odometry_only=False)}
    for channel in info.channels:
        json_channel = not channel.schema.startswith("foxglove.")
        assert channel.message_encoding == ("json" if json_channel else "protobuf")
        assert channel.schema_encoding == ("jsonschema" if json_channel else "protobuf")
    # everything handed to the SDK is in the file: it was closed properly
    assert info.counts() == session.counts()
    assert info.metadata["bioslam"] == {"input": "ring"}
    assert "zstd" in info.compression
    text = format_summary(info)
    assert all(f"{t.topic} " in text for t in tp.TOPICS)


def test_recording_counts_follow_the_run(recorded, ring_scans):
    path, _, result = recorded
    system = result.system
    counts = summarize(path).counts()
    duration = ring_scans[-1].stamp - ring_scans[0].stamp
    assert counts[tp.SCAN] == len(ring_scans)  # every scan is kept
    # 10 Hz poses; the transforms: odom -> base_link per scan plus map -> odom with the poses
    assert counts[tp.SLAM_POSE] == counts[tp.ODOMETRY_POSE]
    assert abs(counts[tp.SLAM_POSE] - (duration / 0.1 + 1)) <= 2
    assert counts[tp.TF] == counts[tp.SCAN] + counts[tp.SLAM_POSE]
    assert counts[tp.VIEW] == len(system.records)  # one per look of the view cells
    # throttled: the map and the cognitive map at most every 2 s (plus the final one)
    for topic in (tp.MAP, tp.COGNITIVE_MAP):
        assert duration / 4 <= counts[topic] <= duration / 2 + 2
    assert duration / 2 <= counts[tp.POSE_CELLS_XY] <= duration + 2
    assert counts[tp.POSE_CELLS_XY] == counts[tp.BOUNDARY_CELLS] == counts[tp.POSE_CELLS_STATE]


def test_recording_log_times_are_the_scans_and_never_go_back(recorded, ring_scans):
    path, _, _ = recorded
    stamps = np.array([round(s.stamp * 1e9) for s in ring_scans])
    times = log_times(path)
    assert set(times) == {t.topic for t in tp.topics_for(False)}
    for topic, t in times.items():
        assert np.all(np.diff(t) >= 0), topic
        assert np.isin(t, stamps).all(), topic  # on the log's clock, at a scan
    np.testing.assert_array_equal(times[tp.SCAN], stamps)


def test_recorded_events_are_the_loop_closures_and_rejections(recorded):
    path, _, result = recorded
    cmap = result.system.cognitive_map
    assert cmap.loop_closures > 0 and cmap.rejected_closures > 0
    logs = [m.message for _, _, m in decoded_messages(path, [tp.LOG])]
    assert sum(x.startswith("loop closure accepted") for x in logs) == cmap.loop_closures
    assert sum(x.startswith("loop closure rejected") for x in logs) == cmap.rejected_closures
    assert logs[-1].startswith("run finished")
    views = [m for _, _, m in decoded_messages(path, [tp.VIEW])]
    assert [v["view_id"] for v in views] == [r.view_id for r in result.system.records]
    # a closure held back until another confirmed it has no look of its own
    looks = cmap.loop_closures - result.system.confirmed_later
    assert sum(v["event"] == "loop" for v in views) == looks
    assert all(0.0 < v["activity"] <= 1.0 for v in views)
    assert views[-1]["views"] == result.system.view_cells.num_views


def test_recorded_scene_is_the_final_cognitive_map(recorded):
    path, _, result = recorded
    cmap = result.system.cognitive_map
    *_, (_, _, scene) = decoded_messages(path, [tp.COGNITIVE_MAP])
    (entity,) = scene.entities
    assert entity.frame_id == tp.MAP_FRAME
    centres = np.array([(s.pose.position.x, s.pose.position.y) for s in entity.spheres])
    # every experience at its relaxed pose, then the current one drawn larger
    np.testing.assert_allclose(centres[:-1], cmap.experience_poses[:, :2], atol=1e-9)
    np.testing.assert_allclose(centres[-1], cmap.experience_poses[cmap.current, :2])
    odometry_links, loop_links, trajectory = entity.lines
    links = cmap.links
    assert len(loop_links.points) == 2 * sum(link.kind == "loop" for link in links)
    assert len(odometry_links.points) == 2 * sum(link.kind == "odometry" for link in links)
    assert loop_links.color.r > 0.8 and loop_links.color.g < 0.2  # loop closures in red
    final = result.system.trajectory().poses
    assert (trajectory.points[-1].x, trajectory.points[-1].y) == pytest.approx(
        tuple(final[-1, :2]), abs=0.05
    )


def test_recorded_transforms_chain_to_the_slam_pose(recorded):
    path, _, _ = recorded
    odom_base: dict[int, np.ndarray] = {}
    map_odom: dict[int, np.ndarray] = {}
    slam: dict[int, np.ndarray] = {}

    def planar(translation, rotation) -> np.ndarray:
        return np.array([translation.x, translation.y, 2.0 * math.atan2(rotation.z, rotation.w)])

    topics = [tp.TF, tp.SLAM_POSE]
    for topic, ns, m in decoded_messages(path, topics):
        if topic == tp.SLAM_POSE:
            slam[ns] = planar(m.pose.position, m.pose.orientation)
            continue
        for t in m.transforms:
            store = map_odom if t.parent_frame_id == tp.MAP_FRAME else odom_base
            assert (t.parent_frame_id, t.child_frame_id) in {
                (tp.MAP_FRAME, tp.ODOM_FRAME), (tp.ODOM_FRAME, tp.BASE_FRAME)
            }
            store[ns] = planar(t.translation, t.rotation)
    assert len(slam) > 100 and set(slam) == set(map_odom)
    for ns, pose in slam.items():
        chained = compose(map_odom[ns], odom_base[ns])
        np.testing.assert_allclose(chained[:2], pose[:2], atol=1e-9)
        assert math.remainder(chained[2] - pose[2], 2 * math.pi) == pytest.approx(0, abs=1e-9)


def test_recorded_scans_are_the_input_with_no_returns_left_out(recorded, ring_scans):
    path, _, _ = recorded
    for k, (_, ns, m) in enumerate(decoded_messages(path, [tp.SCAN])):
        if k % 250:
            continue
        scan = ring_scans[k]
        assert ns == round(scan.stamp * 1e9) and m.frame_id == tp.BASE_FRAME
        assert (m.start_angle, m.end_angle) == (scan.angles[0], scan.angles[-1])
        ranges = np.array(m.ranges)
        valid = scan.valid_mask
        np.testing.assert_array_equal(ranges[valid], scan.ranges[valid].astype(np.float32))
        assert np.isnan(ranges[~valid]).all()


def _grid_cell(grid, x: float, y: float) -> np.ndarray:
    """The RGBA of the cell at map point (x, y) of a decoded RGBA grid."""
    col = int((x - grid.pose.position.x) / grid.cell_size.x)
    row = int((y - grid.pose.position.y) / grid.cell_size.y)
    offset = row * grid.row_stride + col * grid.cell_stride
    return np.frombuffer(grid.data, dtype=np.uint8)[offset : offset + 4]


def test_recorded_map_has_the_walls_where_the_world_has_them(recorded):
    path, _, _ = recorded
    *_, (_, _, grid) = decoded_messages(path, [tp.MAP])
    assert grid.frame_id == tp.MAP_FRAME
    # world points in the map frame (the route starts at START, heading +x)
    walls = [(4.0, 0.02), (4.0, 5.98), (7.98, 1.0), (0.02, 5.0), (3.0, 1.52), (6.48, 2.5)]
    free = [(4.0, 0.75), (4.0, 5.25), (7.25, 2.0), (0.75, 3.0)]
    for x, y in walls:
        r, _g, _b, a = _darkest_near(grid, x - START[0], y - START[1])
        assert a == 255 and r < 60, (x, y)
    for x, y in free:
        r, _g, _b, a = _grid_cell(grid, x - START[0], y - START[1])
        assert a == 255 and r > 200, (x, y)
    inside_block = _grid_cell(grid, 4.0 - START[0], 3.0 - START[1])
    assert inside_block[3] == 0  # never seen: transparent


def _darkest_near(grid, x: float, y: float) -> np.ndarray:
    """The darkest observed cell within one cell of (x, y) (a wall's cell may be its
    neighbour); unknown cells (transparent) count as white."""
    res = grid.cell_size.x
    steps = (-1, 0, 1)
    cells = [_grid_cell(grid, x + dx * res, y + dy * res) for dx in steps for dy in steps]
    return min(cells, key=lambda c: int(c[0]) if c[3] else 256)


def test_interrupted_run_still_closes_the_file(ring_scans, tmp_path):
    def interrupted():
        for k, scan in enumerate(ring_scans):
            if k == 150:
                raise KeyboardInterrupt
            yield scan

    path = tmp_path / "stopped.mcap"
    with Session(record=path) as session:
        result = run_slam(interrupted(), options=_quiet(), observer=session.observer)
        session.finish(result.system)
    assert result.interrupted
    counts = summarize(path).counts()
    assert counts[tp.SCAN] == 150
    assert counts == session.counts()


def test_odometry_only_recording_has_no_neurons(ring_scans, tmp_path):
    path = tmp_path / "odo.mcap"
    options = RunOptions(progress=False, warm_up=False, odometry_only=True)
    with Session(record=path, odometry_only=True) as session:
        result = run_slam(ring_scans[:120], options=options, observer=session.observer)
        session.finish(result.system)
    assert set(summarize(path).counts()) == {t.topic for t in tp.topics_for(True)}
    assert tp.POSE_CELLS_XY not in summarize(path).counts()


def test_run_command_records_and_reports_it(tmp_path, capsys):
    sim = tmp_path / "sim"
    assert main(["sim", "--lidar", "rplidar", "--duration", "12", "--seed", "4",
                 "--out", str(sim)]) == 0  # fmt: skip
    out, mcap = tmp_path / "out", tmp_path / "rec" / "run.mcap"
    code = main(["run", str(sim / "scans"), "--out", str(out), "--no-progress",
                 "--record", str(mcap)])  # fmt: skip
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["recording"]["path"] == str(mcap)
    assert summary["recording"]["bytes"] == mcap.stat().st_size
    assert summarize(mcap).counts()[tp.SCAN] == summary["scans"]
    assert json.loads((out / "summary.json").read_text())["recording"]["path"] == str(mcap)


def test_run_command_rejects_a_directory_to_record_into(tmp_path, capsys):
    code = main(["run", str(tmp_path / "x.bag"), "--out", str(tmp_path / "o"),
                 "--record", str(tmp_path)])  # fmt: skip
    assert code == 2
    assert "is a directory" in capsys.readouterr().err


def test_layout_file_is_current_and_names_only_recorded_topics():
    from bioslam.recording.layout import LAYOUT_FILE, layout_json

    regenerate = "regenerate it: python -m bioslam.recording.layout"
    assert LAYOUT_FILE.read_text() == layout_json(), regenerate
    text = LAYOUT_FILE.read_text()
    known = {t.topic for t in tp.TOPICS}
    named = {word.strip('"').split(".")[0] for word in text.split() if word.startswith('"/')}
    named = {n.rstrip('",:') for n in named}
    assert named <= known
    for topic in (tp.SCAN, tp.MAP, tp.COGNITIVE_MAP, tp.BOUNDARY_CELLS, tp.POSE_CELLS_XY,
                  tp.POSE_CELLS_THETA, tp.VIEW, tp.LOG):
        assert topic in named


def test_render_draws_the_recorded_map_and_cognitive_map(recorded, tmp_path):
    from bioslam.recording.render import render

    path, _, result = recorded
    drawn = render(path, tmp_path / "map.png")
    cmap = result.system.cognitive_map
    assert drawn["experiences"] == len(cmap) + 1  # and the current one
    assert drawn["links"] >= cmap.num_links
    assert (tmp_path / "map.png").stat().st_size > 10_000


# --- live ------------------------------------------------------------------------------------

LIVE_TOPICS = {tp.SCAN, tp.TF, tp.MAP, tp.COGNITIVE_MAP, tp.VIEW, tp.BOUNDARY_CELLS,
               tp.POSE_CELLS_XY, tp.SLAM_POSE}  # fmt: skip


async def _watch(url: str, wanted: set[str], deadline: float) -> tuple[dict, dict, list[int]]:
    """Connect, subscribe to every advertised channel, and collect messages until each wanted
    topic has sent one (or the deadline passes)."""
    from websockets.asyncio.client import connect

    channels: dict[int, dict] = {}
    received: dict[str, list[tuple[int, bytes]]] = {}
    times: list[int] = []
    async with connect(url, subprotocols=["foxglove.sdk.v1"], open_timeout=5) as ws:
        while time.monotonic() < deadline and not wanted <= set(received):
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=1.0)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "advertise":
                    fresh = {c["id"]: c for c in message["channels"]}
                    channels.update(fresh)
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": cid, "channelId": cid} for cid in fresh
                    ]}))  # fmt: skip
            elif frame[0] == 1:  # message data: subscription id, log time, payload
                sub, ns = struct.unpack_from("<IQ", frame, 1)
                received.setdefault(channels[sub]["topic"], []).append((ns, frame[13:]))
            elif frame[0] == 2:  # time
                times.append(struct.unpack_from("<Q", frame, 1)[0])
    return channels, received, times


def test_live_server_serves_the_channels_while_the_run_goes(ring_scans):
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory

    stop = threading.Event()

    def paced():  # a run that lasts until the client has seen enough (bounded below)
        for scan in ring_scans:
            if stop.is_set():
                return
            time.sleep(0.01)
            yield scan

    with Session(live_port=0, announce=False) as session:
        assert session.url.startswith("ws://127.0.0.1:")
        outcome: dict = {}
        worker = threading.Thread(
            target=lambda: outcome.update(result=run_slam(paced(), options=_quiet(),
                                                          observer=session.observer)))
        worker.start()
        try:
            deadline = time.monotonic() + 30.0
            channels, received, times = asyncio.run(_watch(session.url, LIVE_TOPICS, deadline))
        finally:
            stop.set()
            worker.join(timeout=30.0)
    assert not worker.is_alive()
    assert set(received) >= LIVE_TOPICS, f"missing {LIVE_TOPICS - set(received)}"
    stamps = {round(s.stamp * 1e9) for s in ring_scans}
    assert {ns for ns, _ in received[tp.SCAN]} <= stamps
    assert times and set(times) <= stamps  # the server's clock is the log's
    # a scan decodes with the schema the server advertised
    scan_channel = next(c for c in channels.values() if c["topic"] == tp.SCAN)
    assert scan_channel["schemaName"] == "foxglove.LaserScan"
    schema = Schema(id=1, name=scan_channel["schemaName"], encoding="protobuf",
                    data=base64.b64decode(scan_channel["schema"]))
    decode = DecoderFactory().decoder_for("protobuf", schema)
    ns, payload = received[tp.SCAN][0]
    scan = next(s for s in ring_scans if round(s.stamp * 1e9) == ns)
    assert len(decode(payload).ranges) == scan.num_beams


def test_live_view_nobody_watches_builds_no_messages(ring_scans):
    with Session(live_port=0, announce=False) as session:
        result = run_slam(ring_scans[:200], options=_quiet(), observer=session.observer)
    assert result.error is None
    assert session.counts("live") == {}


def test_nothing_asked_for_means_no_observer():
    session = Session()
    with session:
        assert session.observer is None
    assert session.summary() == {}


def test_bad_ports_and_paths_are_refused_with_the_flag_named(tmp_path):
    with pytest.raises(ValueError, match="--live 70000"):
        Session(live_port=70000)
    with pytest.raises(ValueError, match="is a directory"):
        Session(record=tmp_path)
    with Session(live_port=0, announce=False) as first, pytest.raises(RuntimeError, match="--live"):
        Session(live_port=first.port, announce=False).__enter__()
    assert Path(tmp_path).is_dir()


def test_throttle_waits_longer_for_larger_content():
    from bioslam.recording.rates import Throttle

    throttle = Throttle(period=2.0, per_second=1000.0)
    times = np.arange(0.0, 60.0, 0.1)
    small = [t for t in times if throttle.ready(float(t), size=500)]
    assert len(small) == 30  # every 2 s
    throttle = Throttle(period=2.0, per_second=1000.0)
    large = [t for t in times if throttle.ready(float(t), size=6000)]
    assert len(large) == 10 and np.allclose(np.diff(large), 6.0)  # every 6 s


def test_degenerate_stretches_are_logged_once_at_their_start_and_end():
    import foxglove

    from bioslam.recording.recorder import Recorder

    recorder = Recorder(foxglove.Context())
    logged: list[tuple[float, str]] = []
    recorder._log = lambda ns, level, text, name: logged.append((ns / 1e9, text))
    flags = [False] * 5 + [True] * 10 + [False] + [True] * 3 + [False] * 20 + [True] * 2
    for k, degenerate in enumerate(flags):
        recorder._degeneracy(round(k * 0.1 * 1e9), degenerate, 0.01)
    texts = [text for _, text in logged]
    assert len(texts) == 3, texts  # the flicker at 1.5 s continues the first stretch
    assert texts[0].startswith("odometry: degenerate matches start")
    assert "ended after 1.3 s" in texts[1]
    assert logged[1][0] == pytest.approx(2.9)  # 1 s after the last degenerate match
    assert texts[2].startswith("odometry: degenerate matches start")


def test_the_file_is_closed_when_the_run_disappears(ring_scans, tmp_path):
    path = tmp_path / "orphan.mcap"
    session = Session(record=path).__enter__()
    run_slam(ring_scans[:50], options=_quiet(), observer=session.observer)
    output = session.outputs[0]
    output.tap.flush()
    output._enqueue(None, wait=True)  # let the pipe take what is queued, then
    output._pump.join()
    output.process.stdin.close()  # what the writing process sees when the run is killed
    assert output.process.wait(timeout=120) == 0
    assert summarize(path).counts()[tp.SCAN] == 50


def test_every_event_since_the_last_look_is_logged_once():
    """Two closures accepted and two refused between looks, and a packet that died out
    twice: each is a message of its own, counted, and none is logged again at the next look."""
    from types import SimpleNamespace

    from bioslam.recording.tap import Tap

    links = [SimpleNamespace(kind="odometry", source=0, target=1)]
    cmap = SimpleNamespace(
        num_links=1, loop_closures=0, rejected_closures=0, link=lambda k: links[k]
    )
    system = SimpleNamespace(cognitive_map=cmap, pose_cells=SimpleNamespace(collapses=0))
    tap = Tap(lambda batch: None)
    tap._events(1, system)
    links += [SimpleNamespace(kind="loop", source=5, target=1),
              SimpleNamespace(kind="odometry", source=1, target=6),
              SimpleNamespace(kind="loop", source=6, target=2)]  # fmt: skip
    cmap.num_links, cmap.loop_closures, cmap.rejected_closures = 4, 2, 2
    system.pose_cells.collapses = 2
    tap._events(2, system)
    tap._events(3, system)  # nothing new
    logs = [(item[1], item[3]) for item in tap._batch if item[0] == "log"]
    assert [text for _, text in logs] == [
        "loop closure accepted: experience 5 -> 1 (1 so far)",
        "loop closure accepted: experience 6 -> 2 (2 so far)",
        "loop closure rejected: the scan registration did not fit (1 so far)",
        "loop closure rejected: the scan registration did not fit (2 so far)",
        "pose cells: the activity packet died out and was re-seeded at its last centre",
        "pose cells: the activity packet died out and was re-seeded at its last centre",
    ]
    assert {ns for ns, _ in logs} == {2}
