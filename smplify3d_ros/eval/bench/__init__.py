"""`smplify3d bench`: accuracy of SMPLify-3D and its baselines on simulated scenes (thesis Sec. 4).

Modules: `methods` (the methods, one scene scored), `studies` (the main table and the studies),
`report` (rows, bands and tables), `plots`, `cli` (the command line).

Every scene comes from a bench scenario of the simulator (`sim.bench.scenarios`, through
`smplify3d_ros.sim.world.simulate_scenario`) with a seed, so all methods, sensors and noise levels see
the same people. Seeds 0-999 are for tuning (`smplify3d tune`), the bench reports from 1000 on
(`sim.bench`). Per detected person the bench runs the node's frame path (`frame_fitter.FrameFitter`:
people selected, keypoints undistorted, each person's points cut out of the full scan), then each
method's fit, and scores the body against the ground truth:

- `builtin_init_three_stage`: the robot path, the headline: the built-in initializer and the three
  stages, as on a robot without an image HMR network;
- with an upstream HMR (the simulator's CLIFF-like estimate, `SimFrame.hmr_init`, that no robot has):
  `hmr_init_root_aligned` (the estimate with its hip midpoint moved onto the truth's: the usual
  image-only figure), `hmr_init` (as it is), `hmr_init_icp` (+ rigid ICP, `FitOptions(optimize=False)`),
  `smplify3d_single_stage` (Eq. 2 in one stage), `smplify3d_three_stage` (Eq. 11-14);
- `builtin_init_truth_start` (only when named in `--methods`): the robot path with the true body as
  one more start, an oracle: how far a perfect search would take the fits, and where the objective's
  own minimum near the truth lies.

Errors in mm: PVE (vertices), MPJPE over the 19 body joints, PA-MPJPE, MPJPE after aligning the hip
midpoints; LiDAR methods are always reported unaligned. The main table reports the robot path by
distance and heading band with the fits' own chamfer verdict. `--study` runs one of the thesis's sweeps
(sensors, range noise, angular noise, drop-out, LiDAR density and distance, ablation) on the `lab`
scenario and saves a plot.
"""
