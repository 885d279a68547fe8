"""`smplify3d tune`: two trials on one scene with tiny iteration counts write a loadable profile, stay
inside the search space, resume from their journal and repeat exactly with the same sampler seed."""

from __future__ import annotations

import argparse

import pytest
import yaml

pytest.importorskip("optuna")

from smplify3d_ros.config import load_config  # noqa: E402
from smplify3d_ros.eval import tune  # noqa: E402

TINY_SPACE = (
    tune.Param("iterations.0", 0, 1, False, True, "tiny: a test"),
    tune.Param("iterations.1", 1, 2, False, True, "tiny: a test"),
    tune.Param("iterations.2", 0, 1, False, True, "tiny: a test"),
    tune.Param("weights.pose", 0.5, 10.0, True, False, "as in the real space"),
    tune.Param("lr", 0.005, 0.05, True, False, "as in the real space"),
)


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    tune.add_arguments(parser)
    return parser.parse_args(argv)


@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.setattr(tune, "SEARCH_SPACE", TINY_SPACE)
    # a one-person scene and a one-step initializer keep each trial under a second
    return ["--scenes", "1", "--no-progress", "--set", "fitting.init.refine_iterations=1",
            "--set", "fitting.profiles.robot.iterations=[1,1,1]", "--set", "sim.bench.scenarios.robot.n_people=[1,1]"]


def run_tune(tmp_path, argv: list[str], name: str) -> tuple[str, dict]:
    out = tmp_path / f"{name}.yaml"
    assert tune.run(parse([*argv, "--storage", str(tmp_path / f"{name}.journal"), "--out", str(out)])) == 0
    text = out.read_text()
    return text, yaml.safe_load(text)


def test_two_trials_write_a_profile_load_config_accepts(tmp_path, tiny, capsys):
    text, doc = run_tune(tmp_path, [*tiny, "--trials", "2"], "a")
    robot = doc["fitting"]["profiles"]["robot"]
    assert 0 <= robot["iterations"][0] <= 1 and 1 <= robot["iterations"][1] <= 2
    assert 0.5 <= robot["weights"]["pose"] <= 10.0 and 0.005 <= robot["lr"] <= 0.05
    config = load_config(tmp_path / "a.yaml")
    assert config.fitting.optimizer.lr == robot["lr"]
    assert config.fitting.init.refine_iterations == 1  # the --set values the scores were measured with
    header = [line for line in text.splitlines() if line.startswith("#")]
    assert any("2 trials" in line and "tuning seeds 0-0" in line for line in header)
    assert any("Report seeds 1000-1000" in line for line in header)
    assert any("Objective: mean MPJPE" in line and "capped at 500 mm" in line for line in header)
    assert "# searched [0.5, 10] log, was 3" in text  # weights.pose: its range and the value it replaced
    printed = capsys.readouterr().out
    assert "best trial" in printed and "report seeds 1000-1000" in printed and "capped" in printed


def test_a_journal_resumes_and_a_seeded_search_repeats(tmp_path, tiny):
    import optuna

    _, first = run_tune(tmp_path, [*tiny, "--trials", "2", "--no-report"], "b")
    _, again = run_tune(tmp_path, [*tiny, "--trials", "3", "--no-report"], "b")  # one more trial
    storage = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(tmp_path / "b.journal")))
    trials = optuna.load_study(study_name="tune-robot", storage=storage).trials
    assert len(trials) == 3
    assert trials[0].params["weights.pose"] == pytest.approx(3.0)  # trial 0: the profile as it was
    _, other = run_tune(tmp_path, [*tiny, "--trials", "2", "--no-report"], "c")  # a fresh journal, same seed
    assert other == first


def test_tuning_refuses_report_seeds_and_another_search_in_its_journal(tmp_path, tiny, capsys):
    assert tune.run(parse([*tiny, "--seed", "1000", "--storage", str(tmp_path / "d.journal")])) == 2
    assert "leave the tuning seeds" in capsys.readouterr().err
    run_tune(tmp_path, [*tiny, "--trials", "1", "--no-report"], "e")
    argv = [*tiny, "--trials", "1", "--iteration-cost", "1.0", "--storage", str(tmp_path / "e.journal")]
    assert tune.run(parse(argv)) == 2
    assert "holds another search" in capsys.readouterr().err


def test_profile_overrides_fill_lists_from_the_profile():
    profile = load_config().fitting.profiles["robot"]
    out = tune.profile_overrides("robot", {"iterations.1": 7, "weights.shape": 2.5}, profile)
    robot = out["fitting"]["profiles"]["robot"]
    assert robot["iterations"] == [profile.iterations[0], 7, profile.iterations[2]]
    assert robot["weights"] == {"shape": 2.5}
    assert set(tune.base_values(profile, tune.SEARCH_SPACE)) == {p.key for p in tune.SEARCH_SPACE}
    for p in tune.SEARCH_SPACE:  # the profile as it is lies inside the space, so trial 0 is a real trial
        assert p.low <= tune.base_values(profile, (p,))[p.key] <= p.high, p.key
