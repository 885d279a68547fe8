"""The bench's plots (matplotlib, written to the directory the user gives)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from smplify3d_ros.eval.bench.methods import METHODS, SENSOR_LABELS, Case


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_methods(rows: Sequence[dict[str, Any]], path: Path, title: str) -> Path:
    """Grouped bars: PVE, MPJPE (mean and median), PA-MPJPE per method."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    keys = [("pve_mm", "PVE"), ("mpjpe_mm", "MPJPE"), ("mpjpe_median_mm", "MPJPE median"),
            ("pa_mpjpe_mm", "PA-MPJPE")]  # fmt: skip
    x = np.arange(len(rows))
    width = 0.8 / len(keys)
    for k, (key, label) in enumerate(keys):
        values = [r[key] if r[key] is not None else np.nan for r in rows]
        bars = ax.bar(x + (k - (len(keys) - 1) / 2) * width, values, width, label=label)
        ax.bar_label(bars, fmt="%.0f", fontsize=7)
    ax.set_xticks(x, [METHODS[r["method"]].label or r["method"] for r in rows], rotation=20, ha="right")
    ax.set_ylabel("error (mm)")
    ax.set_yscale("log")
    ax.set_title(title, pad=28)
    ax.legend(ncol=len(keys), fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def plot_sweep(rows: Sequence[dict[str, Any]], path: Path, xlabel: str, title: str) -> Path:
    """Mean (solid) and median (dotted) MPJPE of each method against the swept value; the median shows
    the typical person, the mean also the failures (ICP not converging, people without points)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for method in dict.fromkeys(r["method"] for r in rows):
        pick = sorted((r for r in rows if r["method"] == method), key=lambda r: r["value"])
        x = [r["value"] for r in pick]
        label = METHODS[method].label
        (line,) = ax.plot(x, [r["mpjpe_mm"] for r in pick], "o-", label=f"{label}: mean")
        median = [r["mpjpe_median_mm"] for r in pick]
        ax.plot(x, median, "s:", color=line.get_color(), alpha=0.7, label=f"{label}: median")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("MPJPE (mm)")
    ax.set_ylim(bottom=0)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_sensors(rows: Sequence[dict[str, Any]], path: Path, title: str) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    sensors = list(dict.fromkeys(r["sensor"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    x = np.arange(len(sensors))
    width = 0.8 / len(methods)
    by = {(r["method"], r["sensor"]): r for r in rows}
    for k, method in enumerate(methods):
        values = [by[(method, s)]["mpjpe_mm"] if (method, s) in by else np.nan for s in sensors]
        offset = x + (k - (len(methods) - 1) / 2) * width
        bars = ax.bar(offset, values, width, label=f"{METHODS[method].label}: mean")
        ax.bar_label(bars, fmt="%.0f", fontsize=8)
        medians = [by[(method, s)]["mpjpe_median_mm"] if (method, s) in by else np.nan for s in sensors]
        ax.plot(offset, medians, "k_", markersize=14, markeredgewidth=2, label="median" if k == 0 else None)
    ax.set_xticks(x, [SENSOR_LABELS.get(s, s) for s in sensors])
    ax.set_ylabel("MPJPE (mm)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def plot_density(cases: Sequence[Case], path: Path, title: str) -> Path:
    """MPJPE against Eq. 9 density (log bins) and against distance, per sensor."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    density_edges = np.array([1, 10, 25, 50, 100, 200, 400, 800, 1600, 3200], dtype=float)
    distance_edges = np.arange(2.0, 22.0, 2.0)
    for sensor in dict.fromkeys(c.sensor for c in cases):
        for method, style in (("smplify3d_three_stage", "o-"), ("hmr_init_icp", "x:")):
            pick = [c for c in cases if c.sensor == sensor and c.method == method]
            if not pick:
                continue
            kind = "3-stage" if method.startswith("smplify") else "init+ICP"
            label = f"{SENSOR_LABELS.get(sensor, sensor)} {kind}"
            for ax, key, edges in (
                (axes[0], "density", density_edges),
                (axes[1], "distance_m", distance_edges),
            ):
                xs, ys = _binned(pick, key, edges)
                ax.plot(xs, ys, style, label=label, alpha=0.9 if style == "o-" else 0.5)
    axes[0].set_xscale("log")
    for ax in axes:
        ax.set_yscale("log")
    axes[0].set_xlabel("LiDAR density on the person (points / m², Eq. 9)")
    axes[1].set_xlabel("distance (m)")
    for ax in axes:
        ax.set_ylabel("median MPJPE per bin (mm)")
        ax.grid(alpha=0.3, which="both")
    axes[0].axvline(200, color="grey", lw=0.8, ls="--")
    axes[1].legend(fontsize=7, ncol=2)
    fig.suptitle(title)
    return _save(fig, path)


def _binned(
    cases: Sequence[Case], key: str, edges: np.ndarray, min_count: int = 3
) -> tuple[list[float], list[float]]:
    values = np.array([getattr(c, key) for c in cases])
    errors = np.array([c.mpjpe for c in cases])
    xs, ys = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = (values >= lo) & (values < hi)
        if inside.sum() >= min_count:
            xs.append(float(np.median(values[inside])))
            ys.append(float(np.median(errors[inside])))
    return xs, ys


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path



def plot_bands(rows: Sequence[dict[str, Any]], hmr_rows: Sequence[dict[str, Any]], path: Path, title: str) -> Path:
    """Mean and median MPJPE of the robot path per band (distance, then heading); the three-stage fit
    with an upstream HMR as ticks, for scale."""
    plt = _pyplot()
    pick = [r for r in rows if r["band"] != "all" and r["n"]]
    fig, ax = plt.subplots(figsize=(9, 4.5))
    x = np.arange(len(pick))
    for k, (key, label) in enumerate((("mpjpe_mm", "MPJPE mean"), ("mpjpe_median_mm", "MPJPE median"))):
        bars = ax.bar(x + (k - 0.5) * 0.38, [r[key] for r in pick], 0.38, label=f"robot path: {label}")
        ax.bar_label(bars, fmt="%.0f", fontsize=7)
    by = {(r["band"], r["subset"]): r for r in hmr_rows}
    hmr = [by.get((r["band"], r["subset"]), {}).get("mpjpe_median_mm") for r in pick]
    if any(v is not None for v in hmr):
        ax.plot(x, [np.nan if v is None else v for v in hmr], "k_", markersize=16, markeredgewidth=2,
                label="three-stage with an upstream HMR: median")
    ax.set_xticks(x, [f"{r['subset']}\n(n={r['n']})" for r in pick], fontsize=8)
    ax.set_ylabel("MPJPE (mm)")
    ax.set_yscale("log")
    top = max(r["mpjpe_mm"] for r in pick) if pick else 1.0
    ax.set_ylim(top=top * 4.0)  # room for the legend above the bars
    ax.set_title(title)
    ax.legend(fontsize=8, loc="upper left", ncol=3)
    ax.grid(axis="y", alpha=0.3, which="both")
    return _save(fig, path)
