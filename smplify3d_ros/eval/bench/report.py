"""Summaries of a bench run: JSON rows, Markdown tables, the project's target lines."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from smplify3d_ros.eval.bench.methods import SENSOR_LABELS, TARGET_RATIO, Case


def summarize(cases: Sequence[Case], method: str, sensor: str, **extra: Any) -> dict[str, Any]:
    """One JSON row (mm; std = standard deviation over people)."""
    pick = [c for c in cases if c.method == method and c.sensor == sensor]

    def mean(key: str) -> float | None:
        return round(float(np.mean([getattr(c, key) for c in pick])), 2) if pick else None

    def std(key: str) -> float | None:
        return round(float(np.std([getattr(c, key) for c in pick])), 2) if pick else None

    scene_seconds = {(c.scene, c.value): c.seconds for c in pick}  # one fit call per scene
    row = {
        "method": method,
        "sensor": sensor,
        "n": len(pick),
        "pve_mm": mean("pve"),
        "mpjpe_mm": mean("mpjpe"),
        "pa_mpjpe_mm": mean("pa_mpjpe"),
        "mpjpe_root_aligned_mm": mean("mpjpe_root_aligned"),
        "pve_std_mm": std("pve"),
        "mpjpe_std_mm": std("mpjpe"),
        "mpjpe_median_mm": round(float(np.median([c.mpjpe for c in pick])), 2) if pick else None,
        "seconds_per_person": round(sum(scene_seconds.values()) / len(pick), 3) if pick else None,
    }
    row.update(extra)
    return row


def markdown_table(rows: Sequence[dict[str, Any]], extra_columns: Sequence[str] = ()) -> str:
    def fmt(x: Any) -> str:
        return "-" if x is None else f"{x:.1f}"

    def seconds(x: Any) -> str:
        return "-" if x is None else f"{x:.2f}"

    head = [
        "method",
        "sensor",
        *extra_columns,
        "n",
        "PVE mm",
        "MPJPE mm",
        "PA-MPJPE mm",
        "MPJPE root-aligned mm",
        "MPJPE median mm",
        "s / person",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] * 2 + ["---:"] * (len(head) - 2)) + "|"]
    for r in rows:
        extra = [str(r.get(c, "")) for c in extra_columns]
        lines.append(
            f"| {r['method']} | {SENSOR_LABELS.get(r['sensor'], r['sensor'])} | "
            + "".join(f"{e} | " for e in extra)
            + f"{r['n']} | {fmt(r['pve_mm'])} ± {fmt(r['pve_std_mm'])} | {fmt(r['mpjpe_mm'])} ± "
            f"{fmt(r['mpjpe_std_mm'])} | {fmt(r['pa_mpjpe_mm'])} | {fmt(r['mpjpe_root_aligned_mm'])} | "
            f"{fmt(r.get('mpjpe_median_mm'))} | {seconds(r.get('seconds_per_person'))} |"
        )
    return "\n".join(lines)


def target_lines(rows: Sequence[dict[str, Any]]) -> list[str]:
    """The project's ratio targets, for every sensor that has both rows."""
    lines = []
    by = {(r["method"], r["sensor"]): r for r in rows}
    for sensor in dict.fromkeys(r["sensor"] for r in rows):
        icp, ours = by.get(("hmr_init_icp", sensor)), by.get(("smplify3d_three_stage", sensor))
        if not icp or not ours or not icp["mpjpe_mm"] or ours["mpjpe_mm"] is None:
            continue
        ratio = ours["mpjpe_mm"] / icp["mpjpe_mm"]
        target = TARGET_RATIO.get(sensor)
        verdict = (
            "" if target is None else f" (target <= {target:.2f}: {'met' if ratio <= target else 'NOT met'})"
        )
        lines.append(
            f"{SENSOR_LABELS.get(sensor, sensor)}: three-stage / init+ICP MPJPE = "
            f"{ours['mpjpe_mm']:.1f} / {icp['mpjpe_mm']:.1f} = {ratio:.2f}{verdict}"
        )
    return lines

