"""Nav2 clearing of people who left (params/nav2/people_layer.yaml), on a replayed bag.

A small model of Nav2's ObstacleLayer (nav2_costmap_2d, Jazzy: per update, every clearing observation is
raytraced from its sensor's origin with Costmap2D's Bresenham, cells set free up to raytrace_max_range;
then every marking observation marks its points' cells; each source keeps only points inside its height
band, and marks only within obstacle_max_range) is fed the replay's ~/body_points and ~/clearing_points,
frame by frame, in the bag's base_link frame. The bundled walk has a person crossing; in its last two
frames the detector sees nobody."""

from __future__ import annotations

import math
from pathlib import Path

import node_support
import numpy as np
import pytest
import yaml

from msg_adapters import RosbagsFactory, read_points, write_keypoints
from smplify3d_ros.runtime.transforms import TransformGraph

REPO = Path(__file__).resolve().parent.parent
WALK = REPO / "bags" / "walk_sqlite3"
LAYER = yaml.safe_load((REPO / "params/nav2/people_layer.yaml").read_text())[
    "local_costmap"]["local_costmap"]["ros__parameters"]["people_layer"]
RESOLUTION, SIZE = 0.05, 400  # a 20 m x 20 m grid around base_link
EMPTY_FRAMES = 2


class ObstacleLayerModel:
    def __init__(self, layer: dict) -> None:
        self.layer = layer
        self.sources = {name: layer[name] for name in layer["observation_sources"].split()}
        self.grid = np.zeros((SIZE, SIZE), bool)

    @staticmethod
    def cell(x: float, y: float) -> tuple[int, int]:
        return int(math.floor(x / RESOLUTION)) + SIZE // 2, int(math.floor(y / RESOLUTION)) + SIZE // 2

    def update(self, observations: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
        """observations: source name -> (points (N, 3), sensor origin (3,)), both in the global frame."""
        kept = {}
        for name, (points, origin) in observations.items():
            src = self.sources[name]
            band = (points[:, 2] >= src["min_obstacle_height"]) & (points[:, 2] <= src["max_obstacle_height"])
            kept[name] = (points[band], origin)
        for name, (points, origin) in kept.items():
            if self.sources[name]["clearing"]:
                for p in points:
                    self._raytrace(origin, p, self.sources[name]["raytrace_max_range"])
        for name, (points, origin) in kept.items():
            src = self.sources[name]
            if not src["marking"]:
                continue
            low, high = self.layer["min_obstacle_height"], self.layer["max_obstacle_height"]
            band = (points[:, 2] >= low) & (points[:, 2] <= high)
            near = np.linalg.norm(points - origin, axis=1) < src["obstacle_max_range"]
            for x, y, _ in points[band & near]:
                self.grid[self.cell(x, y)] = True

    def _raytrace(self, origin: np.ndarray, end: np.ndarray, max_range: float) -> None:
        """Costmap2D::raytraceLine with a MarkCell(FREE_SPACE) action (min range 0)."""
        (x0, y0), (x1, y1) = self.cell(*origin[:2]), self.cell(*end[:2])
        dx, dy = x1 - x0, y1 - y0
        dist = math.hypot(dx, dy)
        scale = 1.0 if dist == 0 else min(1.0, int(max_range / RESOLUTION) / dist)
        sx, sy = (1 if dx > 0 else -1), (1 if dy > 0 else -1)
        if abs(dx) >= abs(dy):
            a, b, step_a, step_b = abs(dx), abs(dy), (sx, 0), (0, sy)
        else:
            a, b, step_a, step_b = abs(dy), abs(dx), (0, sy), (sx, 0)
        error, (x, y) = a // 2, (x0, y0)
        for _ in range(min(int(scale * a), a)):
            self.grid[x, y] = False
            x, y = x + step_a[0], y + step_a[1]
            error += b
            if error >= a:
                x, y, error = x + step_b[0], y + step_b[1], error - a
        self.grid[x, y] = False

    def cells(self) -> set[tuple[int, int]]:
        return {tuple(c) for c in np.argwhere(self.grid)}


def _bag_where_people_leave(tmp_path: Path) -> Path:
    """bags/walk_sqlite3 with the keypoints of its last frames emptied: the detector sees nobody."""
    from rosbags.rosbag2 import Reader, Writer

    factory = RosbagsFactory()
    store = factory.typestore
    out = tmp_path / "walk_people_leave"
    with Reader(WALK) as reader, Writer(out, version=9) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store) for c in reader.connections}
        n_keypoints = sum(c.msgcount for c in reader.connections if c.topic == "/keypoints")
        seen = 0
        for conn, t, raw in reader.messages():
            if conn.topic == "/keypoints":
                seen += 1
                if seen > n_keypoints - EMPTY_FRAMES:
                    msg = store.deserialize_cdr(raw, conn.msgtype)
                    empty = write_keypoints(np.zeros((0, 17, 3)), np.zeros(0, np.int64), msg.header.stamp,
                                            msg.header.frame_id, factory)
                    raw = store.serialize_cdr(empty, conn.msgtype)
            writer.write(conns[conn.id], t, raw)
    return out


def _frames(path: Path) -> list[dict[str, np.ndarray]]:
    """Per frame, in order: the replay's body points and clearing ray ends (camera or output frame)."""
    from rosbags.highlevel import AnyReader

    wanted = {"/smplify3d/body_points": "body", "/smplify3d/clearing_points": "clearing"}
    frames: dict[int, dict] = {}
    with AnyReader([path]) as reader:
        for conn, _, raw in reader.messages([c for c in reader.connections if c.topic in wanted]):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            frames.setdefault(stamp, {})[wanted[conn.topic]] = (read_points(msg).xyz, str(msg.header.frame_id))
    return [frames[s] for s in sorted(frames)]


def _to_base(graph: TransformGraph, points: np.ndarray, frame_id: str) -> tuple[np.ndarray, np.ndarray]:
    T = graph.lookup("base_link", frame_id)
    return points @ T[:3, :3].T + T[:3, 3], T[:3, 3]


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    from smplify3d_ros.replay import replay_bag

    if not (WALK / "metadata.yaml").exists():
        pytest.skip("bags/walk_sqlite3 is not in this checkout")
    tmp = tmp_path_factory.mktemp("nav2")
    bag = _bag_where_people_leave(tmp)
    summary = replay_bag(bag, tmp / "out.mcap", progress=False, config=node_support.config(),
                         node_config=node_support.node_config(), fitter=node_support.fitter())
    graph = TransformGraph()
    from rosbags.highlevel import AnyReader

    with AnyReader([WALK]) as reader:
        for conn, _, raw in reader.messages([c for c in reader.connections if c.topic == "/tf_static"]):
            graph.add(reader.deserialize(raw, conn.msgtype))
    return summary, _frames(tmp / "out.mcap"), graph


def _run(frames, graph, layer: dict, sources: dict[str, str]) -> list[tuple[set, set]]:
    """(cells marked after the update, cells of that frame's body points) per frame."""
    model = ObstacleLayerModel(layer)
    out = []
    for frame in frames:
        obs = {name: _to_base(graph, *frame[kind]) for name, kind in sources.items()}
        model.update(obs)
        mark = ObstacleLayerModel(layer)
        mark.update({n: o for n, o in obs.items() if sources[n] == "body"})
        out.append((model.cells(), mark.cells()))
    return out


def test_people_marks_clear_when_people_leave(replayed):
    summary, frames, graph = replayed
    assert summary.frames_published == len(frames) >= 4 and summary.people_fitted >= 2
    steps = _run(frames, graph, LAYER, {"people": "body", "people_clearing": "clearing"})
    with_people, gone = steps[:-EMPTY_FRAMES], steps[-EMPTY_FRAMES:]
    for marked, current in with_people:
        assert current and marked == current, "the layer holds this frame's people, nobody's older positions"
    walked = set().union(*(c for _, c in with_people)) - with_people[-1][1]
    assert len(walked) > 10, "the person moved: cells of earlier positions were marked, then cleared"
    for marked, current in gone:
        assert current == set() and marked == set(), "nobody seen: nothing left marked"


def test_body_points_alone_never_clear_a_person_who_left(replayed):
    _, frames, graph = replayed
    alone = {**LAYER, "observation_sources": "people", "people": {**LAYER["people"], "clearing": True,
                                                                  "raytrace_max_range": 6.0}}
    steps = _run(frames, graph, alone, {"people": "body"})
    marked_after_leaving = steps[-1][0]
    assert len(marked_after_leaving) > 10, "an empty ~/body_points has no ray to clear along"


@pytest.mark.parametrize("origin", [(0.0, 0.0), (0.013, 0.027), (0.031, -0.017)])
def test_the_clearing_fan_reaches_every_cell_within_range(origin):
    from msg_adapters.outputs import clearing_points
    from smplify3d_ros.types import CameraModel

    K = np.array([[320.0, 0, 320.0], [0, 320.0, 240.0], [0, 0, 1]])
    fan = clearing_points(CameraModel(K, 640, 480), range_m=6.0, resolution_m=RESOLUTION)
    o = np.array([*origin, 0.4])
    ends = np.stack([fan[:, 2], -fan[:, 0], -fan[:, 1]], axis=1) + o  # optical -> base_link axes

    def missed(points: np.ndarray) -> int:
        model = ObstacleLayerModel(LAYER)
        model.grid[:] = True
        for p in points:
            model._raytrace(o, p, 6.0)
        centres = (np.argwhere(model.grid) - SIZE // 2 + 0.5) * RESOLUTION
        return int((np.linalg.norm(centres - o[:2], axis=1) < 5.9).sum())

    assert missed(ends) == 0
    at_range = o + (ends - o) * 0.5  # the same rays, ending at the clearing range: Bresenham leaves gaps
    assert missed(at_range) > 100
