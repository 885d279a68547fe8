"""A camera-driver stand-in for test_node_qos.py: a bag's input topics published from a process of its own.

    python qos_bag_publisher.py BAG RELIABILITY DEPTH

Creates one publisher per input topic with the given QoS, prints `ready`, waits for a line on stdin, then
publishes every input message at the bag's recorded timing (CDR bytes as recorded, so 10 Hz for the
bundled bags) and prints `published <image count>`. The caller sets ROS_DOMAIN_ID and the discovery range.
"""

from __future__ import annotations

import sys
import time

INPUT_TYPES = {
    "/camera/color/image_raw": "sensor_msgs/msg/Image",
    "/camera/color/camera_info": "sensor_msgs/msg/CameraInfo",
    "/velodyne_points": "sensor_msgs/msg/PointCloud2",
    "/keypoints": "sensor_msgs/msg/PointCloud2",
}


def main(bag: str, reliability: str, depth: int) -> None:
    import rclpy
    from rclpy.duration import Duration
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosbags.rosbag2 import Reader

    from msg_adapters import RclpyFactory

    rclpy.init()
    node = Node("qos_bag_publisher")
    policy = ReliabilityPolicy.RELIABLE if reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT
    qos = QoSProfile(depth=depth, reliability=policy)
    factory = RclpyFactory()
    pubs = {topic: node.create_publisher(factory.message_class(t), topic, qos) for topic, t in INPUT_TYPES.items()}
    print("ready", flush=True)
    sys.stdin.readline()
    images = 0
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic in pubs]
        start_wall, start_bag = time.monotonic(), None
        for conn, t, raw in reader.messages(connections=conns):
            start_bag = t if start_bag is None else start_bag
            delay = (t - start_bag) * 1e-9 - (time.monotonic() - start_wall)
            if delay > 0:
                time.sleep(delay)
            pubs[conn.topic].publish(bytes(raw))  # the recorded CDR bytes, as a driver would send them
            images += conn.topic == "/camera/color/image_raw"
    print(f"published {images}", flush=True)
    for pub in pubs.values():  # reliable: until every reader acknowledged the last messages (best effort: at once)
        pub.wait_for_all_acked(Duration(seconds=2.0))
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]))
