"""smplify3d_ros: SMPLify-3D human mesh recovery from camera keypoints and LiDAR, for ROS 2."""

__version__ = "0.1.0"
