"""What the drivers (the ROS node and the bag replay) share around the core frame path.

    messages (rclpy or rosbags) -> `messages.to_frame` -> `FrameFitter` (the core) -> `outputs` -> messages

`processor.MessageProcessor` owns that step for one synchronized set of messages (stamps checked, drops
counted); `sync` builds the synchronizer both drivers use; `config` holds the drivers' settings.
"""
