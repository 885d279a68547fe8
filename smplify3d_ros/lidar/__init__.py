"""Person point extraction from full LiDAR scans: `extract.extract_people` (steps in ground.py,
cluster.py, associate.py), its parameters in config.py, and `smplify3d bench-extract` in bench.py."""
