"""Person point extraction from full LiDAR scans: `extract.extract_people` (steps in ground.py,
cluster.py, associate.py) and its parameters in config.py."""
