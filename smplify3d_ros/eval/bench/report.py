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
        # one fit call per scene: each person's share of it, so that any subset of people averages right
        "seconds_per_person": round(float(np.mean([c.seconds / c.people_in_fit for c in pick])), 3) if pick else None,
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



# -- the robot path's report: bands of distance and heading, pose families, fit quality ------------------
HEADING_BANDS = ("facing", "side-on", "back")


def distance_bands(edges: Sequence[float]) -> list[tuple[str, float, float]]:
    """(label, low, high) per band of `edges` (m)."""
    return [(f"{lo:g}-{hi:g} m", lo, hi) for lo, hi in zip(edges[:-1], edges[1:])]


def distance_band(distance: float, edges: Sequence[float]) -> str:
    """The band of a distance; people just outside the edges (a turned body's pelvis moves a few cm)
    count in the nearest band."""
    k = int(np.clip(np.searchsorted(edges, distance, side="right") - 1, 0, len(edges) - 2))
    return distance_bands(edges)[k][0]


def heading_band(heading_deg: float, bands_deg: Sequence[float]) -> str:
    """facing below bands_deg[0], side-on below bands_deg[1], back from there (true heading vs the camera)."""
    return HEADING_BANDS[int(np.searchsorted(bands_deg, heading_deg, side="right"))]


def fit_quality(pick: Sequence[Case], missed_chamfer_m: float) -> dict[str, float | None]:
    """What the fits say of themselves: mean chamfer (mm) of fits with points, the fraction of those whose
    chamfer exceeds `missed_chamfer_m` (they missed their points), the fraction fitted from the image
    alone (flag image_only), and the median of the people's extracted points. None where no case has the
    quantity (methods that do not fit)."""
    with_points = [c.chamfer_m for c in pick if c.chamfer_m is not None]
    fitted = [c for c in pick if c.chamfer_m is not None or c.flags]
    return {
        "points_median": float(np.median([c.num_points for c in pick])) if pick else None,
        "chamfer_mm": round(1000.0 * float(np.mean(with_points)), 1) if with_points else None,
        "missed_fraction": round(float(np.mean(np.array(with_points) > missed_chamfer_m)), 3) if with_points else None,
        "image_only_fraction": round(float(np.mean(["image_only" in c.flags for c in fitted])), 3) if fitted else None,
    }


def chamfer_verdict(cases: Sequence[Case], method: str, missed_m: float, off_mm: float) -> dict[str, Any]:
    """How far the fits' own "missed" verdict (chamfer > `missed_m`) agrees with the truth (MPJPE >
    `off_mm`), over `method`'s fits that have points."""
    pick = [c for c in cases if c.method == method and c.chamfer_m is not None]
    missed = [c.chamfer_m > missed_m for c in pick]
    off = [c.mpjpe > off_mm for c in pick]
    both = sum(m and o for m, o in zip(missed, off))
    return {"method": method, "fits_with_points": len(pick), "missed": sum(missed), "off": sum(off),
            "missed_and_off": both, "missed_chamfer_m": missed_m, "off_mpjpe_mm": off_mm}


def surface_summary(cases: Sequence[Case], method: str) -> dict[str, Any]:
    """Mean and median chamfer and points-to-mesh distance (mm) of `method`'s fits with points, beside those of the
    true bodies against the same points, both by one rule (`Case.scored_chamfer_m`): how near a perfect
    fit could come. (The chamfer's mesh half counts every vertex facing the LiDAR, hidden by another body
    or between the rings of a ring scanner or not, so the truth's own chamfer is far from 0.)"""
    pick = [c for c in cases if c.method == method and c.scored_chamfer_m is not None
            and c.truth_chamfer_m is not None]

    fields = {"chamfer": ("scored_chamfer_m", "truth_chamfer_m"),
              "points_to_mesh": ("scored_points_to_mesh_m", "truth_points_to_mesh_m")}
    out: dict[str, Any] = {"method": method, "fits_with_points": len(pick)}
    for name, (fit_key, truth_key) in fields.items():
        for prefix, key in (("", fit_key), ("truth_", truth_key)):
            values = np.array([getattr(c, key) for c in pick], dtype=np.float64)
            out[f"{prefix}{name}_mm"] = round(1000.0 * float(values.mean()), 1) if len(values) else None
            out[f"{prefix}{name}_median_mm"] = round(1000.0 * float(np.median(values)), 1) if len(values) else None
    return out


def surface_line(v: dict[str, Any]) -> str:
    def mm(key: str) -> str:
        mean, median = v[f"{key}_mm"], v[f"{key}_median_mm"]
        return "-" if mean is None else f"{mean:.1f} mm (median {median:.1f})"

    return (f"{v['method']}: {v['fits_with_points']} fits with points, every visible vertex: chamfer "
            f"{mm('chamfer')}, the true bodies {mm('truth_chamfer')}; points to the mesh "
            f"{mm('points_to_mesh')}, the true bodies {mm('truth_points_to_mesh')}")


def verdict_line(v: dict[str, Any]) -> str:
    return (f"{v['method']}: {v['missed']} of {v['fits_with_points']} fits with points missed them (chamfer > "
            f"{v['missed_chamfer_m']:g} m), {v['missed_and_off']} of those are more than {v['off_mpjpe_mm']:g} mm "
            f"off; of the {v['off']} fits that far off, the chamfer flagged {v['missed_and_off']}")


def band_rows(cases: Sequence[Case], method: str, sensor: str, bench: Any, missed_m: float) -> list[dict[str, Any]]:
    """One row for all of `method`'s cases, one per distance band, one per heading band."""
    pick = [c for c in cases if c.method == method and c.sensor == sensor]
    groups: list[tuple[str, str, list[Case]]] = [("all", "all", pick)]
    edges = bench.distance_bands_m
    for label, _, _ in distance_bands(edges):
        groups.append(("distance", label, [c for c in pick if distance_band(c.distance_m, edges) == label]))
    for label in HEADING_BANDS:
        groups.append(("heading", label,
                       [c for c in pick if heading_band(c.heading_deg, bench.heading_bands_deg) == label]))
    return [summarize(group, method, sensor, band=kind, subset=label, **fit_quality(group, missed_m))
            for kind, label, group in groups]


def family_rows(cases: Sequence[Case], method: str, sensor: str, missed_m: float) -> list[dict[str, Any]]:
    """One row per true pose family (sorted by name)."""
    pick = [c for c in cases if c.method == method and c.sensor == sensor]
    return [summarize(group, method, sensor, band="family", subset=family, **fit_quality(group, missed_m))
            for family in sorted({c.family for c in pick})
            for group in [[c for c in pick if c.family == family]]]


def band_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown: one line per band row (`band_rows`, `family_rows`)."""
    def num(x: Any, digits: int = 1) -> str:
        return "-" if x is None else f"{x:.{digits}f}"

    def pct(x: Any) -> str:
        return "-" if x is None else f"{100.0 * x:.0f} %"

    head = ["subset", "n", "MPJPE mm", "PA-MPJPE mm", "PVE mm", "MPJPE median mm", "points (median)",
            "chamfer mm", "missed", "image only", "s / person"]
    lines = ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    for r in rows:
        lines.append(f"| {r['subset']} | {r['n']} | {num(r['mpjpe_mm'])} | {num(r['pa_mpjpe_mm'])} | "
                     f"{num(r['pve_mm'])} | {num(r.get('mpjpe_median_mm'))} | {num(r.get('points_median'), 0)} | "
                     f"{num(r.get('chamfer_mm'))} | "
                     f"{pct(r.get('missed_fraction'))} | {pct(r.get('image_only_fraction'))} | "
                     f"{num(r.get('seconds_per_person'), 2)} |")
    return "\n".join(lines)
