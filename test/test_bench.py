"""`smplify3d bench`: a tiny run (1 scene, 1 person, a few iterations) gives the JSON schema and a plot."""

from __future__ import annotations

import argparse
import json

import pytest

from smplify3d_ros.eval import bench

FAST = [
    "--set", "fitting.profiles.robot.iterations=[1,2,1]",
    "--set", "fitting.profiles.robot.single_stage_iterations=2",
    "--set", "fitting.init.refine_iterations=1",
]  # fmt: skip


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    return parser.parse_args(argv)


def test_tiny_run_writes_the_json_schema_and_a_plot(tmp_path, capsys):
    out = tmp_path / "bench.json"
    args = parse(["--scenes", "1", "--people", "1-1", "--json", str(out), "--plot-dir", str(tmp_path),
                  "--no-progress", *FAST])  # fmt: skip
    assert bench.run(args) == 0
    doc = json.loads(out.read_text())
    assert [row["method"] for row in doc["rows"]] == list(bench.MAIN_METHODS)
    for row in doc["rows"]:
        assert set(bench.ROW_KEYS) <= set(row)
        assert row["sensor"] == "vlp16"
        assert row["n"] == 1
        for key in bench.ROW_KEYS[3:]:
            assert isinstance(row[key], float) and row[key] >= 0.0
    rows = {row["method"]: row for row in doc["rows"]}
    # the same HMR estimate, scored with and without root alignment
    aligned = rows["hmr_init_root_aligned"]["mpjpe_mm"]
    assert rows["hmr_init"]["mpjpe_root_aligned_mm"] == pytest.approx(aligned, abs=0.02)
    assert rows["hmr_init"]["mpjpe_mm"] > rows["hmr_init_root_aligned"]["mpjpe_mm"]
    assert len(doc["cases"]) == len(bench.MAIN_METHODS)
    assert (tmp_path / "bench_vlp16.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "| smplify3d_three_stage | VLP-16 |" in printed


def test_study_rows_carry_the_swept_value(tmp_path, monkeypatch):
    """A sweep study with two levels runs each level and plots MPJPE against the value."""
    monkeypatch.setitem(
        bench.SWEEPS, "dropout", bench.Sweep("dropout", (0.0, 0.5), lambda p: p, "drop-out fraction")
    )
    out = tmp_path / "study.json"
    args = parse(["--study", "dropout", "--scenes", "1", "--people", "1-1", "--json", str(out),
                  "--plot-dir", str(tmp_path), "--no-progress", *FAST])  # fmt: skip
    assert bench.run(args) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["method"], r["value"]) for r in rows] == [
        (m, v) for v in (0.0, 0.5) for m in bench.STUDY_METHODS
    ]
    assert all(r["study"] == "dropout" for r in rows)
    assert (tmp_path / "study_dropout_vlp16.png").exists()


@pytest.mark.parametrize(("name", "key"), [("ouster64", "os1_64"), ("os1_32", "os1_32"), ("vlp16", "vlp16")])
def test_sensor_names(name, key):
    assert bench.resolve_sensor(name) == key


def test_overrides_become_a_nested_mapping():
    args = parse(["--set", "fitting.profiles.robot.iterations=[4,10,4]", "--set", "fitting.seed=3"])
    assert bench.overrides_from(args.overrides) == {
        "fitting": {"profiles": {"robot": {"iterations": [4, 10, 4]}}, "seed": 3}
    }
