"""Switches of one fit, for the benchmark's baselines and ablations (the defaults are the method)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class FitOptions:
    """Switches used by the benchmark's baselines and ablations (the defaults are the method)."""

    optimize: bool = True  # run the stages (False: init + ICP only)
    use_icp: bool = True
    use_chamfer: bool = True  # L_3D (ablation: no L_3D)
    use_occlusion_prior: bool = True  # L_θocc (ablation)
    use_visibility: bool = True  # visibility filter (ablation: every vertex used by L_3D)
