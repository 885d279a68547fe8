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
    # the headline: the robot path by band; the report seeds by default, the split in the meta
    meta = doc["meta"]
    assert meta["scenario"] == "robot" and meta["seed_set"] == "report"
    assert meta["seeds"] == [1000, 1000] and meta["tuning_seeds"] == [0, 999] and meta["report_seed_start"] == 1000
    bands = doc["bands"]
    assert [(r["band"], r["subset"]) for r in bands] == [
        ("all", "all"), ("distance", "1.5-4 m"), ("distance", "4-8 m"), ("distance", "8-12 m"),
        ("distance", "12-15 m"), ("heading", "facing"), ("heading", "side-on"), ("heading", "back")]
    assert all(r["method"] == methods.ROBOT_METHOD for r in bands)
    assert sum(r["n"] for r in bands if r["band"] == "distance") == bands[0]["n"] == 1
    assert sum(r["n"] for r in bands if r["band"] == "heading") == 1
    assert bands[0]["mpjpe_mm"] == rows[methods.ROBOT_METHOD]["mpjpe_mm"]
    case = next(c for c in doc["cases"] if c["method"] == methods.ROBOT_METHOD)
    assert 0.0 <= case["heading_deg"] <= 180.0 and case["family"] and case["preset"]
    if case["chamfer_m"] is not None:  # a fit with points: its chamfer decides "missed"
        assert bands[0]["missed_fraction"] == float(case["chamfer_m"] > 0.15)
    assert doc["families"][0]["subset"] == case["family"]
    assert doc["coverage"]["fitted"] == 1 and doc["coverage"]["in_scene"] >= 1
    verdict = doc["chamfer_verdict"][0]
    assert verdict["method"] == methods.ROBOT_METHOD
    assert verdict["missed_and_off"] <= min(verdict["missed"], verdict["off"])
    # the fits' chamfer beside the true bodies', scored alike (the truth is what a perfect fit reads)
    surface = {s["method"]: s for s in doc["surface"]}
    robot = surface[methods.ROBOT_METHOD]
    if case["chamfer_m"] is not None:
        assert robot["fits_with_points"] == 1
        assert robot["chamfer_mm"] == pytest.approx(1000 * case["scored_chamfer_m"], abs=0.06)
        assert robot["truth_chamfer_mm"] == pytest.approx(1000 * case["truth_chamfer_m"], abs=0.06)
        assert 0 < case["truth_points_to_mesh_m"] <= case["truth_chamfer_m"]
    hmr_only = next(c for c in doc["cases"] if c["method"] == "hmr_init")
    assert hmr_only["scored_chamfer_m"] is None  # not a fit: no chamfer of its own to score
    assert hmr_only["truth_chamfer_m"] == case["truth_chamfer_m"]  # a fact of the person
    assert (tmp_path / "bench_robot_vlp16.png").stat().st_size > 10_000
    assert (tmp_path / "bench_robot_vlp16_bands.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "Robot path (builtin_init_three_stage" in printed
    assert "With an upstream HMR" in printed and "| smplify3d_three_stage | VLP-16 |" in printed
    assert "wall time" in printed and "seeds 1000-1000: report" in printed
    if case["chamfer_m"] is not None:
        assert f"{methods.ROBOT_METHOD}: 1 fits with points, every visible vertex: chamfer" in printed
        assert robot["truth_chamfer_median_mm"] == robot["truth_chamfer_mm"]  # one fit: median = mean


def test_tuning_seeds_are_named_as_such(tmp_path, capsys):
    out = tmp_path / "tuning.json"
    args = parse(["--scenes", "1", "--seed", "3", "--people", "1-1", "--methods", methods.ROBOT_METHOD,
                  "--json", str(out), "--no-plot", "--no-progress", *FAST])  # fmt: skip
    assert cli.run(args) == 0
    doc = json.loads(out.read_text())
    assert doc["meta"]["seed_set"] == "tuning" and [r["method"] for r in doc["rows"]] == [methods.ROBOT_METHOD]
    captured = capsys.readouterr()
    assert "include tuning seeds" in captured.err
    assert "With an upstream HMR" not in captured.out  # no HMR-seeded method was asked for


def test_the_oracle_start_gives_the_fitter_the_true_body_at_its_hip_midpoint(tmp_path, capsys, monkeypatch):
    """`builtin_init_truth_start` (named in --methods only) hands the fitter each person's true body as one
    more start, its `transl` the true hip midpoint as the built-in starts' are; the robot path gets none,
    and the report prints the two side by side."""
    from smplify3d_ros.frame_fitter import FrameFitter
    from smplify3d_ros.sim import world

    seen, truth = {}, {}
    simulate = world.simulate_scenario

    def remember_truth(*args, **kwargs):
        sim = simulate(*args, **kwargs)
        truth.update({p.person_id: p for p in sim.people})
        return sim

    fit_observed = FrameFitter.fit_observed

    def remember_starts(self, observed, options=None):
        for p in observed.observations:
            seen.setdefault(p.person_id, []).append(p.hypothesis)
        return fit_observed(self, observed, options)

    monkeypatch.setattr(world, "simulate_scenario", remember_truth)
    monkeypatch.setattr(FrameFitter, "fit_observed", remember_starts)
    out = tmp_path / "oracle.json"
    args = parse(["--scenes", "1", "--people", "1-1", "--methods",
                  f"{methods.ROBOT_METHOD},builtin_init_truth_start", "--json", str(out), "--no-plot",
                  "--no-progress", *FAST])  # fmt: skip
    assert cli.run(args) == 0
    assert "builtin_init_truth_start" not in methods.MAIN_METHODS
    doc = json.loads(out.read_text())
    assert [r["method"] for r in doc["rows"]] == [methods.ROBOT_METHOD, "builtin_init_truth_start"]
    (person_id, starts), = seen.items()
    robot, oracle = starts
    assert robot is None
    true = truth[person_id]
    np.testing.assert_allclose(oracle.pose, true.params.pose)
    np.testing.assert_allclose(oracle.shape, true.params.shape)
    np.testing.assert_allclose(oracle.transl, np.asarray(true.keypoints3d, float)[[11, 12]].mean(0), atol=1e-6)
    printed = capsys.readouterr().out
    assert "against a perfect search" in printed and "| builtin_init_truth_start | VLP-16 |" in printed


def test_unknown_scenario_and_method_are_errors(capsys):
    assert cli.run(parse(["--scenario", "moon", "--no-progress"])) == 2
    assert "unknown scenario 'moon'" in capsys.readouterr().err
    assert cli.run(parse(["--methods", "magic", "--no-progress"])) == 2
    assert "unknown methods" in capsys.readouterr().err


@pytest.mark.parametrize(("yaw_deg", "expected"), [(180.0, 0.0), (0.0, 180.0), (90.0, 90.0), (-135.0, 45.0)])
def test_heading_against_the_camera(yaw_deg, expected):
    """A body at x = 0, z = 5 m in the camera frame (y down): yaw about the vertical from facing along +z
    (away from the camera); the heading is measured against the direction back to the camera."""
    from scipy.spatial.transform import Rotation

    up = np.array([0.0, -1.0, 0.0])
    # canonical body (x left, y up, z forward) -> camera frame: y up -> -y, facing +z (away)
    upright = Rotation.from_matrix(np.array([[-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]]))
    root = (Rotation.from_rotvec(np.deg2rad(yaw_deg) * up) * upright).as_rotvec()
    assert methods.heading_to_camera_deg(root, np.array([0.0, 0.3, 5.0]), up) == pytest.approx(expected, abs=1e-6)


def test_band_edges():
    from smplify3d_ros.eval.bench import report

    edges = [1.5, 4.0, 8.0, 12.0, 15.0]
    assert [report.distance_band(d, edges) for d in (1.4, 1.5, 3.99, 4.0, 14.0, 15.2)] == [
        "1.5-4 m", "1.5-4 m", "1.5-4 m", "4-8 m", "12-15 m", "12-15 m"]
    assert [report.heading_band(h, (45.0, 135.0)) for h in (0.0, 44.9, 45.0, 135.0, 135.1, 180.0)] == [
        "facing", "facing", "side-on", "back", "back", "back"]


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


def test_seconds_per_person_is_each_persons_share_of_the_fit_call():
    from smplify3d_ros.eval.bench import report

    def case(pid: int, distance: float) -> methods.Case:
        return methods.Case("builtin_init_three_stage", "vlp16", 0, pid, distance, 10.0, "walking", "child", 20,
                            1.0, False, 1.0, 1.0, 1.0, 1.0, 1.0, seconds=1.2, people_in_fit=3)

    cases = [case(0, 2.0), case(1, 5.0), case(2, 9.0)]
    rows = report.band_rows(cases, "builtin_init_three_stage", "vlp16", type("B", (), {
        "distance_bands_m": [1.5, 4.0, 8.0, 12.0, 15.0], "heading_bands_deg": (45.0, 135.0)})(), 0.15)
    assert [r["seconds_per_person"] for r in rows[:4]] == [0.4, 0.4, 0.4, 0.4]  # one fit of 3 people: 1.2 s


def test_sequences_report_the_warm_fit_time_per_person(tmp_path, capsys):
    """`--sequences` on a 5-frame walk, every second frame fitted (frames 0, 2 and 4): the tracked runs
    time their warm fits (the last two are warm), the single-frame runs have none, and every figure
    lands in the JSON."""
    out = tmp_path / "sequences.json"
    args = parse(["--sequences", "walk", "--scenes", "1", "--frames", "5", "--frame-step", "2", "--json", str(out),
                  "--no-progress", *FAST])  # fmt: skip
    assert cli.run(args) == 0
    doc = json.loads(out.read_text())
    assert doc["meta"]["frame_step"] == 2
    rows = {(r["variant"], r["detector"]): r for r in doc["rows"]}
    assert set(rows) == {(v, d) for v in ("tracked", "single_frame") for d in ("track_ids", "anonymous")}
    tracked = rows[("tracked", "track_ids")]
    assert tracked["fitted"] == 3 and tracked["warm_share"] == pytest.approx(2 / 3)
    assert 0.0 < tracked["warm_ms_per_person"] < tracked["ms_per_person_frame"] * 3
    assert np.isnan(rows[("single_frame", "track_ids")]["warm_ms_per_person"])
    assert "warm fit ms / person (median)" in capsys.readouterr().out
    assert cli.run(parse(["--sequences", "walk", "--frame-step", "0", "--no-progress"])) == 2


def test_sequences_take_the_sensor_aliases_and_refuse_unknown_names_in_one_line(monkeypatch, capsys, tmp_path):
    """`--sequences --sensor ouster64` is the Ouster-64 with its own params profile, as the scenes' runs
    take it (it stopped with an internal error); an unknown sensor or sequence scenario is one line and
    exit status 2, before anything is simulated."""
    from smplify3d_ros.eval import sequences

    seen = {}

    def simulate(seed, sim, scenario, frames, rate, sensor):
        seen["sensor"] = sensor
        return iter(())

    monkeypatch.setattr("smplify3d_ros.sim.world.simulate_sequence", simulate)
    monkeypatch.setattr(sequences, "run_sequence", lambda *args: type("Run", (), {"per_person": lambda self: {}})())
    monkeypatch.setattr(sequences, "summarize", lambda runs: [])
    out = tmp_path / "sequences.json"
    assert cli.run(parse(["--sequences", "walk", "--scenes", "1", "--frames", "2", "--sensor", "ouster64",
                          "--json", str(out), "--no-progress"])) == 0
    assert seen["sensor"] == "os1_64"
    assert json.loads(out.read_text())["meta"]["params"] == "ouster64"
    capsys.readouterr()
    for bad in (["--sequences", "walk", "--sensor", "velodyne"], ["--sequences", "nowhere"]):
        assert cli.run(parse([*bad, "--scenes", "1", "--no-progress"])) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("smplify3d bench: unknown") and "\n" not in err, err
