"""A tiny synthetic Jackal recording for the node and replay tests, written with the msg_adapters writers
and the simulator's message builders (`sim.bag_messages.tf_static_message`, `eval.truth.truth_document`).

People are posed with the body model (as in `smplify3d_ros.eval.synthetic`), stand on a ground plane in
front of a wall; the LiDAR sees points sampled on their sensor-facing surfaces, the ground and the wall;
the detector sees their projected COCO-17 keypoints with pixel noise. Ground truth goes to
`/ground_truth/bodies` in the `~/bodies` schema plus each body's `vertices`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from msg_adapters import RosbagsFactory, camera_model_to_msg, make_pointcloud2, numpy_to_image, write_keypoints
from smplify3d_ros.camera import project_points, transform_points
from smplify3d_ros.eval.synthetic import default_intrinsics, random_pose, sample_surface
from smplify3d_ros.eval.truth import TruthBody, TruthFrame, truth_document
from smplify3d_ros.fitting.init import upright_root_orient
from smplify3d_ros.fitting.visibility import front_facing
from smplify3d_ros.sim.bag_messages import tf_static_message
from smplify3d_ros.types import BodyParams, CameraModel

T0 = 1_700_000_000.0  # s, stamp of the first frame
PERIOD = 0.1  # s, 10 Hz
CAMERA_FRAME, LIDAR_FRAME = "camera_color_optical_frame", "velodyne"
TOPICS = {
    "image": "/camera/color/image_raw",
    "camera_info": "/camera/color/camera_info",
    "points": "/velodyne_points",
    "keypoints": "/keypoints",
    "ground_truth": "/ground_truth/bodies",
    "tf_static": "/tf_static",
}


@dataclass
class TruePerson:
    person_id: int
    params: BodyParams
    keypoints3d: np.ndarray  # (17, 3) camera frame
    vertices: np.ndarray  # (V, 3) camera frame


@dataclass
class FixtureFrame:
    stamp: float
    people: list[TruePerson]
    keypoints: np.ndarray  # (P, 17, 3) detected u, v (distorted px), score
    points_lidar: np.ndarray  # (N, 3) float32


@dataclass
class FixtureBag:
    path: Path
    frames: list[FixtureFrame] = field(default_factory=list)
    camera: CameraModel | None = None


def fixture_camera() -> CameraModel:
    return CameraModel(default_intrinsics(640, 480, 90.0), 640, 480, "plumb_bob",
                       np.array([-0.05, 0.06, 0.0, 0.0, -0.02]))


def pose_person(model, rng: np.random.Generator, pid: int, lateral: float, distance: float, yaw: float,
                ground_y: float) -> TruePerson:
    shape = np.clip(0.5 + 0.15 * rng.standard_normal(len(model.shape_names)), 0.1, 0.9)
    params = BodyParams(model.name, shape, random_pose(model, rng, 0.2), upright_root_orient(yaw),
                        np.array([lateral, 0.0, distance]))
    posed = model.posed([params])[0]
    verts, kp3d = posed.vertices, posed.keypoints3d
    dy = ground_y - verts[:, 1].max()  # stand on the ground
    params.transl = params.transl + [0.0, dy, 0.0]
    return TruePerson(pid, params, kp3d + [0.0, dy, 0.0], verts + [0.0, dy, 0.0])


def surface_points(model, person: TruePerson, sensor: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    faces = model.faces.cpu().numpy()
    front = front_facing(person.vertices, faces, sensor, 0.0)
    return sample_surface(person.vertices, faces[front], n, 0.01, rng)


def background_points(ground_y: float, rng: np.random.Generator) -> np.ndarray:
    ground = np.stack([rng.uniform(-8, 8, 2500), np.full(2500, ground_y), rng.uniform(1.0, 14.0, 2500)], 1)
    wall = np.stack([rng.uniform(-8, 8, 800), ground_y - rng.uniform(0, 3.0, 800), np.full(800, 14.0)], 1)
    return np.concatenate([ground, wall]) + 0.01 * rng.standard_normal((3300, 3))


def make_frames(model, T_cam_lidar: np.ndarray, n_frames: int = 2, n_people: int = 2, seed: int = 0,
                camera: CameraModel | None = None) -> list[FixtureFrame]:
    """People walking slowly across, 10 Hz."""
    rng = np.random.default_rng(seed)
    camera = camera or fixture_camera()
    ground_y = 0.45
    sensor = T_cam_lidar[:3, 3]  # LiDAR origin in the camera frame
    T_lidar_cam = np.linalg.inv(T_cam_lidar)
    starts = [(-1.2 + 2.4 * i / max(n_people - 1, 1), 4.0 + 1.5 * i) for i in range(n_people)]
    yaws = rng.uniform(-0.6, 0.6, n_people)
    frames = []
    for k in range(n_frames):
        people = [pose_person(model, np.random.default_rng(seed * 100 + i), i, x + 0.12 * k, z, yaws[i], ground_y)
                  for i, (x, z) in enumerate(starts)]
        kps = []
        for p in people:
            uv = project_points(p.keypoints3d, camera)
            uv = uv + 1.5 * rng.standard_normal(uv.shape)
            kps.append(np.concatenate([uv, np.full((17, 1), 0.9)], axis=1))
        cloud = [surface_points(model, p, sensor, 260, rng) for p in people] + [background_points(ground_y, rng)]
        points_cam = np.concatenate(cloud)
        frames.append(FixtureFrame(T0 + k * PERIOD, people, np.array(kps),
                                   transform_points(points_cam, T_lidar_cam).astype(np.float32)))
    return frames


def repeat_frames(frames: list[FixtureFrame], n_frames: int) -> list[FixtureFrame]:
    """`n_frames` frames at 10 Hz from T0 cycling through `frames` (a long bag without posing anyone again)."""
    import dataclasses

    return [dataclasses.replace(frames[k % len(frames)], stamp=T0 + k * PERIOD) for k in range(n_frames)]


def truth_json(frame: FixtureFrame, joint_names: list[str], templates: dict | None = None) -> str:
    """The frame's ground-truth document; with `templates`, built once per set of people (repeated
    frames share theirs) and stamped per frame."""
    if templates is not None:
        from msg_adapters import split_stamp

        key = id(frame.people)
        if key not in templates:
            templates[key] = json.dumps({**json.loads(truth_json(frame, joint_names)), "stamp": "STAMP"})
        sec, nanosec = split_stamp(frame.stamp)
        return templates[key].replace('"STAMP"', json.dumps({"sec": sec, "nanosec": nanosec}), 1)
    bodies = [TruthBody(p.person_id, p.params, p.keypoints3d, p.vertices) for p in frame.people]
    return truth_document(TruthFrame(_ns(frame.stamp), CAMERA_FRAME, bodies, joint_names), joint_names)


def fixture_image(camera: CameraModel, frame: FixtureFrame) -> np.ndarray:
    image = np.full((camera.height, camera.width, 3), 150, np.uint8)
    image[camera.height // 2:] = 110
    for p in frame.people:
        uv = project_points(p.vertices[::7], camera)
        ok = np.isfinite(uv).all(axis=1)
        uv = np.round(uv[ok]).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
        image[uv[inside, 1], uv[inside, 0]] = (200, 60, 60)
    return image


def frame_messages(factory, camera: CameraModel, frame: FixtureFrame) -> dict[str, object]:
    """The sensor messages of one frame (rosbags or rclpy, per the factory)."""
    ids = np.array([p.person_id for p in frame.people], np.int64)
    lidar_stamp = frame.stamp + 0.02  # the scan is stamped a little off the image
    return {
        "image": numpy_to_image(fixture_image(camera, frame), "rgb8", frame.stamp, CAMERA_FRAME, factory),
        "camera_info": camera_model_to_msg(camera, frame.stamp, CAMERA_FRAME, factory),
        "points": make_pointcloud2(lidar_stamp, LIDAR_FRAME, {
            "x": frame.points_lidar[:, 0], "y": frame.points_lidar[:, 1], "z": frame.points_lidar[:, 2],
            "intensity": np.full(len(frame.points_lidar), 30.0, np.float32)}, factory),
        "keypoints": write_keypoints(frame.keypoints, ids, frame.stamp, CAMERA_FRAME, factory),
    }


def fixture_messages(frames: list[FixtureFrame], camera: CameraModel, joint_names: list[str], factory,
                     T_cam_lidar: np.ndarray, with_tf: bool = True, with_image: bool = True):
    """(topic name key, message, recording time ns) of a recording, in recording order within each frame."""
    if with_tf:
        tf = tf_static_message(factory, _ns(T0 - 1.0), [(LIDAR_FRAME, CAMERA_FRAME, np.linalg.inv(T_cam_lidar))])
        yield "tf_static", tf, _ns(T0 - 0.5)
    templates: dict = {}
    for frame in frames:
        msgs = frame_messages(factory, camera, frame)
        if with_image:
            yield "image", msgs["image"], _ns(frame.stamp + 0.010)
        yield "camera_info", msgs["camera_info"], _ns(frame.stamp + 0.011)
        yield "points", msgs["points"], _ns(frame.stamp + 0.060)
        yield "keypoints", msgs["keypoints"], _ns(frame.stamp + 0.040)
        truth = factory.make("std_msgs/msg/String", data=truth_json(frame, joint_names, templates))
        yield "ground_truth", truth, _ns(frame.stamp + 0.012)


def _ns(t: float) -> int:
    return int(round(t * 1e9))


TYPES = {"image": "sensor_msgs/msg/Image", "camera_info": "sensor_msgs/msg/CameraInfo",
         "points": "sensor_msgs/msg/PointCloud2", "keypoints": "sensor_msgs/msg/PointCloud2",
         "ground_truth": "std_msgs/msg/String", "tf_static": "tf2_msgs/msg/TFMessage"}


def write_fixture_bag(path: Path, model, T_cam_lidar: np.ndarray, storage: str = "mcap", n_frames: int = 2,
                      n_people: int = 2, seed: int = 0, with_tf: bool = True,
                      frames: list[FixtureFrame] | None = None, with_image: bool = True) -> FixtureBag:
    """Write a rosbag2 directory and return what it holds. `storage`: mcap or sqlite3 with rosbags' writer
    (MCAP uncompressed, chunk CRC 0), or mcap-crc: a bare `path`.mcap file with zstd chunks and their
    CRCs, written with the mcap package (`write_mcap`)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    factory = RosbagsFactory(store)
    camera = fixture_camera()
    frames = frames if frames is not None else make_frames(model, T_cam_lidar, n_frames, n_people, seed, camera)
    messages = fixture_messages(frames, camera, list(model.joint_names), factory, T_cam_lidar, with_tf, with_image)
    if storage == "mcap-crc":
        write_mcap(path, store, ((TOPICS[name], TYPES[name], t, store.serialize_cdr(msg, TYPES[name]))
                                 for name, msg, t in messages))
    else:
        _write_with_rosbags(path, store, storage, messages)
    return FixtureBag(path, frames, camera)


def _write_with_rosbags(path: Path, store, storage: str, messages) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {}
        for name, msg, t in messages:
            if name not in conns:
                conns[name] = writer.add_connection(TOPICS[name], TYPES[name], typestore=store)
            writer.write(conns[name], t, store.serialize_cdr(msg, TYPES[name]))


def write_mcap(path: Path, store, messages) -> Path:
    """A bare MCAP file of (topic, type, log time, CDR bytes), laid out as rosbag2 writes it (profile ros2,
    ros2msg schemas, offered_qos_profiles), zstd chunks with CRCs: written with the mcap package, not with
    the code the tests check."""
    from mcap.writer import CompressionType, Writer

    channels: dict[str, int] = {}
    with open(path, "wb") as handle:
        writer = Writer(handle, compression=CompressionType.ZSTD, enable_crcs=True)
        writer.start(profile="ros2", library="bag_fixture")
        for topic, msgtype, t, raw in messages:
            if topic not in channels:
                definition, _ = store.generate_msgdef(msgtype, ros_version=2)
                schema = writer.register_schema(msgtype, "ros2msg", definition.encode())
                channels[topic] = writer.register_channel(topic, "cdr", schema, {"offered_qos_profiles": ""})
            writer.add_message(channels[topic], log_time=t, data=bytes(raw), publish_time=t)
        writer.finish()
    return path
