"""`smplify3d bench`: accuracy of SMPLify-3D and its baselines on simulated scenes (thesis Sec. 4).

Modules: `methods` (the methods, one scene scored), `studies` (the main table and the studies),
`report` (rows and tables), `plots`, `cli` (the command line).

Every scene comes from the simulator (`smplify3d_ros.sim.world.simulate_scene`) with a seed, so all
methods, sensors and noise levels see the same people. Per detected person the bench cuts the person's
points out of the full scan the way the node does (`frame_fitter.FrameFitter`), gives the fitter the
simulated image-HMR estimate (`SimFrame.hmr_init`, CLIFF-like) as its initial estimate, and scores each
method's body against the ground truth:

- `hmr_init_root_aligned`: the HMR estimate moved so that its hip midpoint sits on the truth's (the
  usual image-only figure, unreachable in real life);
- `hmr_init`: the HMR estimate as it is (unaligned);
- `hmr_init_icp`: HMR estimate + rigid ICP to the person's points (`FitOptions(optimize=False)`);
- `smplify3d_single_stage`: Eq. 2 in one stage (the profile's scheme set to `single_stage`);
- `smplify3d_three_stage`: the default robust three-stage method (Eq. 11-14);
- `builtin_init_three_stage`: three stages from the built-in initializer, without the HMR estimate.

Errors in mm: PVE (vertices), MPJPE over the 19 body joints, PA-MPJPE, MPJPE after aligning the hip
midpoints. LiDAR methods are always reported unaligned. `--study` runs one of the thesis's sweeps
(sensors, range noise, angular noise, drop-out, LiDAR density and distance, ablation) and saves a plot.
"""
