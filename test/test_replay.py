"""`smplify3d replay`: a bag's raw scan in, per-person fits out, on MCAP and sqlite3 bags."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import bag_fixture
import cv2
import node_support
import numpy as np
import pytest

from smplify3d_ros.replay import cli as replay_cli
from smplify3d_ros.replay import reader as replay_reader
from smplify3d_ros.replay import replay_bag
from smplify3d_ros.runtime.transforms import TransformGraph

OUTPUTS = ("/smplify3d/markers", "/smplify3d/joints", "/smplify3d/body_points", "/smplify3d/people",
           "/smplify3d/bodies")


def read_bag(path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from msg_adapters.hri import register_hri_types

    store = register_hri_types(get_typestore(Stores.ROS2_JAZZY))  # the replay also writes hri_msgs topics
    out: dict[str, list] = {}
    with Reader(path) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, store.deserialize_cdr(raw, conn.msgtype)))
    return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_replay_fits_every_person_with_ground_truth_accuracy(storage):
    bag = node_support.fixture_bag(storage)
    summary = node_support.replayed(storage)
    n_people = len(bag.frames[0].people)
    assert summary.frames_synced == 2 and summary.frames_published == 2
    assert summary.people_fitted == 2 * n_people
    assert summary.drops == {}
    assert summary.ground_truth_frames == 2 and summary.people_evaluated == 2 * n_people
    assert summary.people_missed == 0
    # accuracy on clean synthetic data (2 cm LiDAR noise, 1.5 px keypoint noise, robot profile)
    assert summary.mpjpe_mm is not None and summary.mpjpe_mm < 120.0
    assert summary.pve_mm is not None and summary.pve_mm < 140.0
    assert "image_only" not in summary.flags, "every person got LiDAR points from the raw scan"
    for record, frame in zip(summary.frames, bag.frames, strict=True):
        assert record.person_ids == [p.person_id for p in frame.people]
        truth = np.array([p.keypoints3d for p in frame.people])
        assert node_support.mpjpe(record.keypoints3d, truth) < 0.15
    assert np.isfinite(summary.mean_latency_s) and summary.mean_latency_s > 0
    text = summary.text()
    assert "MPJPE" in text and "PVE" in text and f"{summary.people_fitted} people fitted" in text


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_output_bag_holds_inputs_and_outputs(storage):
    summary = node_support.replayed(storage)
    messages = read_bag(summary.output)
    bag = node_support.fixture_bag(storage)
    for topic in ("/camera/color/image_raw", "/velodyne_points", "/keypoints", "/ground_truth/bodies"):
        assert len(messages[topic]) == 2, topic
    for topic in OUTPUTS:
        assert len(messages[topic]) == 2, topic
    assert messages["/diagnostics"], "diagnostics written"
    image_stamps = [(m.header.stamp.sec, m.header.stamp.nanosec) for _, m in messages["/camera/color/image_raw"]]
    for topic in OUTPUTS:
        for (_, msg), stamp in zip(messages[topic], image_stamps, strict=True):
            header = msg.markers[0].header if topic.endswith("markers") else getattr(msg, "header", None)
            if header is not None:
                assert (header.stamp.sec, header.stamp.nanosec) == stamp, topic
                assert header.frame_id == bag_fixture.CAMERA_FRAME
    bodies = [json.loads(m.data) for _, m in messages["/smplify3d/bodies"]]
    assert [[b["id"] for b in d["bodies"]] for d in bodies] == [[p.person_id for p in f.people] for f in bag.frames]
    markers = messages["/smplify3d/markers"][0][1].markers
    meshes = [m for m in markers if m.ns == "mesh"]
    assert len(meshes) == len(bag.frames[0].people) and all(len(m.points) > 1000 for m in meshes)
    joints = messages["/smplify3d/joints"][0][1]
    assert joints.width == 17 * len(bag.frames[0].people)
    times = [t for topic in messages for t, _ in messages[topic]]
    assert min(times) >= int((bag_fixture.T0 - 1.0) * 1e9)


def test_output_mcap_is_standard_mcap():
    """Foxglove reads plain MCAP with ros2msg schemas, ros2 bag needs rosbag2's layout: check with the mcap
    library itself, chunk CRCs included."""
    from mcap.reader import make_reader

    summary = node_support.replayed("mcap")
    with open(summary.output, "rb") as handle:
        reader = make_reader(handle, validate_crcs=True)
        info = reader.get_summary()
        assert info is not None and info.statistics.message_count > 0
        encodings = {s.encoding for s in info.schemas.values()}
        assert encodings == {"ros2msg"}
        topics = {c.topic for c in info.channels.values()}
        assert set(OUTPUTS) <= topics
        assert all(c.message_encoding == "cdr" for c in info.channels.values())
        assert all("offered_qos_profiles" in c.metadata for c in info.channels.values())
        assert {c.compression for c in info.chunk_indexes} == {"zstd"}
        n = sum(1 for _ in reader.iter_messages(topics=["/smplify3d/bodies"]))
        assert n == 2
        assert sum(1 for _ in reader.iter_messages()) == info.statistics.message_count
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    import yaml

    rosbag2 = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert rosbag2["storage_identifier"] == "mcap" and rosbag2["message_count"] == info.statistics.message_count
    assert rosbag2["relative_file_paths"] == [Path(summary.output).name]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_png_shows_the_fit_over_the_image(storage):
    summary = node_support.replayed(storage)
    assert summary.png is not None
    picture = cv2.imread(summary.png)
    camera = bag_fixture.fixture_camera()
    # the camera image with the fit drawn over it, then a square bird's-eye view of the same height
    assert picture.shape == (camera.height, camera.width + camera.height, 3)
    image, top = picture[:, : camera.width], picture[:, camera.width :]
    plain = bag_fixture.fixture_image(camera, node_support.fixture_bag(storage).frames[0])[:, :, ::-1]
    changed = np.any(image != plain, axis=2).mean()
    assert 0.01 < changed < 0.5, "the bodies cover part of the image"
    coloured = (top.max(axis=2) - top.min(axis=2)) > 40  # the body's colour, on grey and white
    assert coloured.sum() > 20, "the top view shows the fitted body"


def test_cli_runs_on_a_bag_file_and_prints_the_summary(capsys, tmp_path):
    parser = argparse.ArgumentParser()
    replay_cli.add_arguments(parser)
    bag = node_support.fixture_bag("sqlite3")
    db3 = next(bag.path.glob("*.db3"))  # a bare .db3 file, without the bag's metadata
    out_dir = tmp_path / "not" / "yet" / "there" / "out"  # missing parents are created
    args = parser.parse_args([str(db3), "-o", str(out_dir), "--max-frames", "1", "--no-progress"])
    assert replay_cli.run(args) == 0
    out = capsys.readouterr().out
    assert "1 synchronized frames, 1 published, 1 people fitted" in out
    assert "MPJPE" in out
    assert (out_dir / "metadata.yaml").exists(), "a name without .mcap gives a bag directory"
    messages = read_bag(out_dir)  # rosbags reads the directory through its metadata.yaml
    assert len(messages["/smplify3d/bodies"]) == 1 and len(messages["/keypoints"]) >= 1


def test_cli_errors_are_messages_not_tracebacks(capsys, tmp_path):
    parser = argparse.ArgumentParser()
    replay_cli.add_arguments(parser)
    assert replay_cli.run(parser.parse_args([str(tmp_path / "missing.mcap"), "--no-progress"])) == 2
    assert "does not exist" in capsys.readouterr().err
    assert replay_cli.run(parser.parse_args([str(node_support.fixture_bag("mcap").path), "--params", "nope",
                                         "--no-progress"])) == 2
    assert "unknown params profile" in capsys.readouterr().err
    # a bag without LiDAR
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Writer(tmp_path / "no_lidar", version=9) as writer:
        conn = writer.add_connection("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
        msg = store.types["sensor_msgs/msg/CameraInfo"]
        from msg_adapters import RosbagsFactory, camera_model_to_msg

        info = camera_model_to_msg(bag_fixture.fixture_camera(), 1.0, "cam", RosbagsFactory(store))
        assert isinstance(info, msg)
        writer.write(conn, 1, store.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
    assert replay_cli.run(parser.parse_args([str(tmp_path / "no_lidar"), "--no-progress"])) == 2
    assert "points topic" in capsys.readouterr().err


def test_topics_found_by_type_when_names_differ(tmp_path):
    """A bag recorded with other topic names: clouds are told apart by their fields."""
    from rosbags.rosbag2 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    src = node_support.fixture_bag("sqlite3").path
    renamed = {"/camera/color/image_raw": "/cam/img", "/velodyne_points": "/lidar/scan", "/keypoints": "/det/kp",
               "/camera/color/camera_info": "/cam/info"}
    with Reader(src) as reader, Writer(tmp_path / "renamed", version=9) as writer:
        conns = {c.id: writer.add_connection(renamed.get(c.topic, c.topic), c.msgtype, typestore=store)
                 for c in reader.connections}
        for conn, t, raw in reader.messages():
            writer.write(conns[conn.id], t, raw)
    with Reader(tmp_path / "renamed") as reader:
        topics = replay_reader.resolve_topics(reader, store, node_support.node_config().topics)
    assert (topics.image, topics.camera_info, topics.points, topics.keypoints) == (
        "/cam/img", "/cam/info", "/lidar/scan", "/det/kp")


def test_static_transforms_compose_chains():
    from msg_adapters import RosbagsFactory

    f = RosbagsFactory()

    def tf(parent, child, xyz):
        return f.make("geometry_msgs/msg/TransformStamped", header=f.header(0.0, parent), child_frame_id=child,
                      transform=f.make("geometry_msgs/msg/Transform",
                                       translation=f.make("geometry_msgs/msg/Vector3", x=xyz[0], y=xyz[1], z=xyz[2]),
                                       rotation=f.make("geometry_msgs/msg/Quaternion", w=1.0)))

    tree = TransformGraph()
    transforms = [tf("base", "lidar", (0, 0, 1)), tf("base", "cam", (1, 0, 0))]
    tree.add(f.make("tf2_msgs/msg/TFMessage", transforms=transforms))
    T = tree.lookup("cam", "lidar")  # lidar points -> cam frame
    np.testing.assert_allclose(T[:3, 3], [-1, 0, 1])
    assert tree.lookup("cam", "unknown") is None


def test_replay_seeds_fits_from_init_bodies_in_the_bag():
    path = node_support.REPO / "bags" / "walk_sqlite3"
    if not (path / "metadata.yaml").exists():
        pytest.skip("bags/ not generated (smplify3d make-bags)")
    from smplify3d_ros.runtime.config import load_node_config

    node = load_node_config(overrides={"node": {"topics": {"init_bodies": "/hmr/bodies"}}})
    summary = replay_bag(path, progress=False, max_frames=1, config=node_support.config(), node_config=node,
                         fitter=node_support.fitter())
    assert summary.frames_published == 1 and summary.people_fitted == 1
    assert summary.flags.get("external_init") == 1, summary.flags
    assert summary.mpjpe_mm is not None and summary.mpjpe_mm < 200.0
