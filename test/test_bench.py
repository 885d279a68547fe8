"""`smplify3d bench`: a tiny run (1 scene, 1 person, a few iterations) gives the JSON schema and a plot."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from smplify3d_ros.eval.bench import cli, methods, studies

FAST = [
    "--set", "fitting.profiles.robot.iterations=[1,2,1]",
    "--set", "fitting.profiles.robot.single_stage_iterations=2",
    "--set", "fitting.init.refine_iterations=1",
]  # fmt: skip


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    return parser.parse_args(argv)


def test_tiny_run_writes_the_json_schema_and_a_plot(tmp_path, capsys):
    out = tmp_path / "bench.json"
    args = parse(["--scenes", "1", "--people", "1-1", "--json", str(out), "--plot-dir", str(tmp_path),
                  "--no-progress", *FAST])  # fmt: skip
    assert cli.run(args) == 0
    doc = json.loads(out.read_text())
    assert [row["method"] for row in doc["rows"]] == list(methods.MAIN_METHODS)
    for row in doc["rows"]:
        assert set(methods.ROW_KEYS) <= set(row)
        assert row["sensor"] == "vlp16"
        assert row["n"] == 1
        for key in methods.ROW_KEYS[3:]:
            assert isinstance(row[key], float) and row[key] >= 0.0
    rows = {row["method"]: row for row in doc["rows"]}
    # the same HMR estimate, scored with and without root alignment
    aligned = rows["hmr_init_root_aligned"]["mpjpe_mm"]
    assert rows["hmr_init"]["mpjpe_root_aligned_mm"] == pytest.approx(aligned, abs=0.02)
    assert rows["hmr_init"]["mpjpe_mm"] > rows["hmr_init_root_aligned"]["mpjpe_mm"]
    assert len(doc["cases"]) == len(methods.MAIN_METHODS)
    assert (tmp_path / "bench_vlp16.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "| smplify3d_three_stage | VLP-16 |" in printed


def run_study(study: str, tmp_path) -> list[dict]:
    """Rows of a one-scene, one-person run of `study` (plots into tmp_path)."""
    out = tmp_path / "study.json"
    args = parse(["--study", study, "--scenes", "1", "--people", "1-1", "--json", str(out),
                  "--plot-dir", str(tmp_path), "--no-progress", *FAST])  # fmt: skip
    assert cli.run(args) == 0
    return json.loads(out.read_text())["rows"]


def test_study_rows_carry_the_swept_value(tmp_path, monkeypatch):
    """A sweep study with two levels runs each level and plots MPJPE against the value."""
    monkeypatch.setitem(
        studies.SWEEPS, "dropout", studies.Sweep("dropout", (0.0, 0.5), lambda p: p, "drop-out fraction")
    )
    rows = run_study("dropout", tmp_path)
    assert [(r["method"], r["value"]) for r in rows] == [
        (m, v) for v in (0.0, 0.5) for m in studies.STUDY_METHODS
    ]
    assert all(r["study"] == "dropout" for r in rows)
    assert (tmp_path / "study_dropout_vlp16.png").exists()


def test_calibration_study_moves_the_lidar_by_the_error(tmp_path, monkeypatch):
    """Each level of the calibration study hands the pipeline a transform off by that error, and fits all
    three methods; with a larger error the init + ICP result moves further from the truth."""
    monkeypatch.setattr(studies, "CALIBRATION_ERRORS", (0.0, 5.0))
    rows = run_study("calibration", tmp_path)
    assert [(r["method"], r["value"]) for r in rows] == [
        (m, v) for v in (0.0, 5.0) for m in studies.CALIBRATION_METHODS
    ]
    icp = {r["value"]: r["mpjpe_mm"] for r in rows if r["method"] == "hmr_init_icp"}
    assert icp[5.0] > icp[0.0] + 20.0  # 5 deg and 5 cm move a body at 3-8 m by decimetres
    assert (tmp_path / "study_calibration_vlp16.png").exists()


def test_miscalibrated_transform_has_the_requested_error():
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [10, -80, 5], degrees=True).as_matrix()
    T[:3, 3] = [0.1, -0.2, 0.3]
    assert np.array_equal(methods.miscalibrated(T, 0.0, seed=4), T)
    wrong = methods.miscalibrated(T, 2.0, seed=4)
    delta = np.linalg.inv(T) @ wrong
    assert np.degrees(Rotation.from_matrix(delta[:3, :3]).magnitude()) == pytest.approx(2.0)
    assert np.linalg.norm(delta[:3, 3]) == pytest.approx(0.02)
    # one direction per scene: a larger error scales the same rotation axis and shift direction
    delta4 = np.linalg.inv(T) @ methods.miscalibrated(T, 4.0, seed=4)
    assert np.allclose(delta4[:3, 3], 2.0 * delta[:3, 3])
    assert np.allclose(Rotation.from_matrix(delta4[:3, :3]).as_rotvec(), 2.0 * Rotation.from_matrix(
        delta[:3, :3]).as_rotvec())
    assert not np.allclose(methods.miscalibrated(T, 2.0, seed=5), wrong)


@pytest.mark.parametrize(("name", "key"), [("ouster64", "os1_64"), ("os1_32", "os1_32"), ("vlp16", "vlp16")])
def test_sensor_names(name, key):
    assert methods.resolve_sensor(name) == key


def test_overrides_become_a_nested_mapping():
    args = parse(["--set", "fitting.profiles.robot.iterations=[4,10,4]", "--set", "fitting.seed=3"])
    assert cli.overrides_from(args.overrides) == {
        "fitting": {"profiles": {"robot": {"iterations": [4, 10, 4]}}, "seed": 3}
    }
