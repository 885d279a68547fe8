"""The synthetic bags in bags/: readable with rosbags, complete, laid out like the drivers', consistent with
their ground truth (docs/bags.md)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.highlevel import AnyReader  # noqa: E402

from msg_adapters import (  # noqa: E402
    camera_info_to_model,
    compressed_to_numpy,
    image_to_numpy,
    read_keypoints,
    read_points,
)
from msg_adapters.pointcloud2 import FLOAT32, UINT16  # noqa: E402
from smplify3d_ros.camera import project_points, transform_points  # noqa: E402
from smplify3d_ros.sim.bags import (  # noqa: E402
    BAGS,
    BAGS_DIR,
    GROUND_TRUTH_TOPIC,
    HMR_TOPIC,
    MAX_BAG_BYTES,
    TF_STATIC_TOPIC,
    BagTopics,
    bag_size,
    read_ground_truth,
)
from smplify3d_ros.sim.config import default_sim_config  # noqa: E402

SPECS = {spec.name: spec for spec in BAGS}
PRESENT = [spec.name for spec in BAGS if (BAGS_DIR / spec.name / "metadata.yaml").exists()]
pytestmark = [pytest.mark.bags,
              pytest.mark.skipif(not PRESENT, reason="no bags in bags/ (run `smplify3d make-bags`)")]


@pytest.fixture(scope="module")
def node_config():
    from smplify3d_ros.runtime.config import load_node_config

    return load_node_config()


@pytest.fixture(scope="module")
def topics(node_config) -> BagTopics:
    return BagTopics.from_config(node_config)


@cache
def ground_truth(name: str) -> dict:
    """{stamp ns: ground-truth bodies} of one bag (read once per test process)."""
    return read_ground_truth(BAGS_DIR / name)


@cache
def messages(name: str) -> dict[str, list[tuple[int, object]]]:
    """topic -> [(log time ns, deserialized message)] of one bag."""
    out: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([BAGS_DIR / name]) as reader:
        for connection, timestamp, raw in reader.messages():
            out.setdefault(connection.topic, []).append(
                (timestamp, reader.deserialize(raw, connection.msgtype))
            )
    return out


def tf_transforms(name: str) -> dict[tuple[str, str], np.ndarray]:
    from scipy.spatial.transform import Rotation

    ((_, msg),) = messages(name)[TF_STATIC_TOPIC]
    out = {}
    for t in msg.transforms:
        T = np.eye(4)
        q = t.transform.rotation
        T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        T[:3, 3] = [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z]
        out[(t.header.frame_id, t.child_frame_id)] = T
    return out


def test_every_bag_is_present_and_both_storage_formats_are_covered():
    assert sorted(PRESENT) == sorted(SPECS), f"missing bags: {sorted(set(SPECS) - set(PRESENT))}"
    assert list(BAGS_DIR.glob("*/*.mcap")) and list(BAGS_DIR.glob("*/*.db3"))


@pytest.mark.parametrize("name", PRESENT)
def test_size_topics_and_counts(name, topics):
    spec = SPECS[name]
    assert bag_size(BAGS_DIR / name) < MAX_BAG_BYTES
    with AnyReader([BAGS_DIR / name]) as reader:
        found = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
    expected = {
        topics.compressed_image: "sensor_msgs/msg/CompressedImage",
        topics.camera_info: "sensor_msgs/msg/CameraInfo",
        topics.points: "sensor_msgs/msg/PointCloud2",
        topics.keypoints: "sensor_msgs/msg/PointCloud2",
        TF_STATIC_TOPIC: "tf2_msgs/msg/TFMessage",
        HMR_TOPIC: "std_msgs/msg/String",
        GROUND_TRUTH_TOPIC: "std_msgs/msg/String",
    }
    if spec.raw_image:
        expected[topics.image] = "sensor_msgs/msg/Image"
    assert found == expected
    assert counts == {t: 1 if t == TF_STATIC_TOPIC else spec.n_frames for t in expected}


@pytest.mark.parametrize("name", PRESENT)
def test_frames_share_stamps_at_10_hz(name, topics):
    msgs = messages(name)
    stamps = {}
    for topic, items in msgs.items():
        if topic == TF_STATIC_TOPIC:
            continue
        header_stamps = [log for log, _ in items]
        if hasattr(items[0][1], "header"):
            header_stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in items]
            assert header_stamps == [log for log, _ in items], f"{topic}: log time != header stamp"
        stamps[topic] = header_stamps
    reference = stamps[topics.camera_info]
    assert all(s == reference for s in stamps.values())
    assert np.allclose(np.diff(reference), 1e8)


@pytest.mark.parametrize("name", PRESENT)
def test_pointcloud_has_the_velodyne_driver_layout(name, topics):
    expected = [
        ("x", 0, FLOAT32),
        ("y", 4, FLOAT32),
        ("z", 8, FLOAT32),
        ("intensity", 12, FLOAT32),
        ("ring", 16, UINT16),
        ("time", 18, FLOAT32),
    ]
    for _, msg in messages(name)[topics.points]:
        assert [(f.name, f.offset, f.datatype) for f in msg.fields] == expected
        assert all(f.count == 1 for f in msg.fields)
        assert (msg.point_step, msg.height, msg.is_bigendian, msg.header.frame_id) == (
            22,
            1,
            False,
            "velodyne",
        )
        cloud = read_points(msg, ["intensity", "ring", "time"])
        assert len(cloud) == msg.width > 5000
        assert set(np.unique(cloud.fields["ring"])) <= set(range(16))
        assert 0.0 <= cloud.fields["time"].min() and cloud.fields["time"].max() < 0.1
        assert 0.0 <= cloud.fields["intensity"].min() and cloud.fields["intensity"].max() <= 255.0
        assert (cloud.xyz[:, 0] >= -1e-3).all()  # the driver's forward view (view_width 180 deg)


@pytest.mark.parametrize("name", PRESENT)
def test_images_and_camera_info(name, topics):
    msgs = messages(name)
    for (_, info), (_, jpeg) in zip(msgs[topics.camera_info], msgs[topics.compressed_image], strict=True):
        camera = camera_info_to_model(info)
        image = compressed_to_numpy(jpeg)
        assert image.shape == (camera.height, camera.width, 3)
        assert info.header.frame_id == jpeg.header.frame_id == topics.camera_frame
    if SPECS[name].raw_image:
        (_, raw), (_, jpeg) = msgs[topics.image][0], msgs[topics.compressed_image][0]
        difference = np.abs(image_to_numpy(raw).astype(float) - compressed_to_numpy(jpeg).astype(float))
        assert difference.mean() < 3.0


@pytest.mark.parametrize("name", PRESENT)
def test_tf_static_matches_the_node_extrinsic(name, node_config, topics):
    transforms = tf_transforms(name)
    T = transforms[(topics.lidar_frame, topics.camera_frame)]
    assert np.allclose(T, node_config.extrinsic.T_lidar_cam(), atol=1e-6)
    assert ("base_link", topics.lidar_frame) in transforms


@pytest.mark.parametrize("name", PRESENT)
def _mesh(body, model) -> np.ndarray:
    """A ground-truth body's vertices: the bag's, or the body model's for its parameters (bags without
    meshes, `BagSpec.truth_vertices`)."""
    return body.vertices if body.vertices is not None else model.posed([body.params])[0].vertices


def _detected_bodies(kps, bodies: dict, camera) -> list:
    """The ground-truth body of each detection: by id, or (anonymous keypoints) by the nearest projection."""
    if (kps.person_ids >= 0).all():
        return [bodies[pid] for pid in kps.person_ids.tolist()]
    assert (kps.person_ids == -1).all(), "a bag gives ids for everyone or for nobody"
    detected = [b for b in bodies.values() if b.detected]
    out = []
    for kp in kps.keypoints:
        seen = kp[:, 2] > 0.3
        out.append(min(detected, key=lambda b: np.linalg.norm(
            project_points(b.keypoints3d, camera)[seen] - kp[seen, :2], axis=1).mean()))
    return out


@pytest.mark.parametrize("name", PRESENT)
def test_ground_truth_matches_the_keypoints(name, topics, anny_model):
    """Detected ids are the keypoint topic's ids (or all -1 in a bag without detector ids); the truth's
    3D keypoints, projected, lie within the detector's noise of the published keypoints."""
    truth = ground_truth(name)
    msgs = messages(name)
    infos = msgs[topics.camera_info]
    keypoint_msgs = msgs[topics.keypoints]
    assert list(truth) == [log for log, _ in keypoint_msgs]
    detector = default_sim_config().detector
    normalized = []
    for (_, info), (stamp, kp_msg) in zip(infos, keypoint_msgs, strict=True):
        camera = camera_info_to_model(info)
        kps = read_keypoints(kp_msg)
        bodies = {b.person_id: b for b in truth[stamp]}
        assert len(kps.person_ids) == sum(b.detected for b in bodies.values())
        matched = _detected_bodies(kps, bodies, camera)
        if SPECS[name].track_ids:
            assert sorted(kps.person_ids.tolist()) == sorted(pid for pid, b in bodies.items() if b.detected)
        else:
            assert len({b.person_id for b in matched}) == len(matched), "each detection is another person"
        for body, detected in zip(matched, kps.keypoints, strict=True):
            uv = project_points(body.keypoints3d, camera)
            top, bottom = body.keypoints3d[:, 1].min(), body.keypoints3d[:, 1].max()  # without the mesh: joints
            height = (np.ptp(project_points(body.vertices, camera, distort=False)[:, 1]) if body.vertices is not None
                      else 1.2 * camera.K[1, 1] * (bottom - top) / body.keypoints3d[:, 2].mean())
            distance = np.linalg.norm(body.keypoints3d[[11, 12]].mean(0))
            rel = detector.sigma_rel_base + detector.sigma_rel_per_m * distance
            sigma = np.hypot(detector.sigma_px_floor, rel * height * 1.6)  # 1.6: the hips' OKS spread
            seen = detected[:, 2] >= 0.75  # confident keypoints: visible, normal detector noise
            normalized += (np.linalg.norm(detected[seen, :2] - uv[seen], axis=1) / sigma).tolist()
    normalized = np.asarray(normalized)
    assert len(normalized) > 20
    assert np.median(normalized) < 1.5
    assert np.mean(normalized < 4.0) > 0.95  # the rest: left/right swaps


@pytest.mark.parametrize("name", PRESENT)
def test_ground_truth_geometry_matches_the_scan_and_the_model(name, topics, anny_model):
    """The truth's vertices lie on the LiDAR returns labelled as the person, and are the body model's
    vertices for the truth's parameters."""
    from scipy.spatial import cKDTree

    truth = ground_truth(name)
    T_lidar_cam = tf_transforms(name)[(topics.lidar_frame, topics.camera_frame)]
    clouds = dict(messages(name)[topics.points])
    checked = 0
    every = 1 if SPECS[name].truth_vertices else 10  # meshes posed here: every 10th frame of long bags
    for k, (stamp, bodies) in enumerate(truth.items()):
        if k % every:
            continue
        points = transform_points(read_points(clouds[stamp]).xyz, np.linalg.inv(T_lidar_cam))
        for body in bodies:
            if body.lidar_points >= 20:  # scan points within 6 cm of the mesh
                distance, _ = cKDTree(_mesh(body, anny_model)).query(points, distance_upper_bound=0.06)
                hits = int(np.isfinite(distance).sum())
                assert hits >= 0.9 * body.lidar_points, (stamp, body.person_id, hits, body.lidar_points)
                checked += 1
            if k == 0:
                posed = anny_model.posed([body.params])[0]
                assert np.abs(posed.vertices - _mesh(body, anny_model)).max() < 2e-3
                assert np.abs(posed.keypoints3d - body.keypoints3d).max() < 2e-3
    assert checked > 0


def test_sqlite3_bag_repeats_the_start_of_the_mcap_bag():
    """Same scenario and seed: the sqlite3 recording holds the MCAP one's first frames, byte for byte."""
    if not {"walk", "walk_sqlite3"} <= set(PRESENT):
        pytest.skip("walk bags missing")
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    short, long = messages("walk_sqlite3"), messages("walk")
    assert set(short) <= set(long)
    for topic, items in short.items():
        for (t1, m1), (t2, m2) in zip(items, long[topic][: len(items)], strict=True):
            assert t1 == t2
            assert bytes(store.serialize_cdr(m1, m1.__msgtype__)) == bytes(
                store.serialize_cdr(m2, m2.__msgtype__)
            )


def test_mcap_files_read_with_the_reference_mcap_reader():
    """An independent MCAP implementation (the `mcap` package, as ROS 2's storage plugin) decodes the zstd
    chunks and finds every message."""
    mcap_reader = pytest.importorskip("mcap.reader")
    for path in sorted(BAGS_DIR.glob("*/*.mcap")):
        with open(path, "rb") as handle:
            reader = mcap_reader.make_reader(handle)
            summary = reader.get_summary()
            assert summary is not None and summary.statistics.message_count > 0
            assert sum(1 for _ in reader.iter_messages()) == summary.statistics.message_count
