"""Refreshes fitted in a helper process (`tracking.refresh_background`): the process fits as the frame path
would, a refresh is taken a fixed number of frames after it started (so that the node and the replay
agree), a better cold fit becomes the next warm start, and a failed process leaves refreshes inline."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from node_support import StubFitter
from test_tracking import NS, observation

from smplify3d_ros.config import load_config
from smplify3d_ros.eval.synthetic import default_intrinsics, make_person
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.frame_fitter import FrameFits, FrameFitter
from smplify3d_ros.tracking.background import BackgroundError, BackgroundFitter
from smplify3d_ros.tracking.tracker import Tracker


class InProcessBackground:
    """A `BackgroundFitter` stand-in: the jobs are fitted when their result is asked for."""

    def __init__(self, fitter) -> None:
        self.fitter, self.jobs, self.taken, self.fail = fitter, [], [], False

    def wait_ready(self, timeout_s):
        return not self.fail

    def submit(self, people, K, lidar_origin, options):
        self.jobs.append(people)
        return len(self.jobs) - 1

    def result(self, job, timeout_s):
        if self.fail:
            raise BackgroundError("the background fitter exited (EOFError)")
        self.taken.append(job)
        return self.fitter.fit(self.jobs[job], None, None)

    def close(self) -> None:
        pass


class BetterColdFits(StubFitter):
    """Cold fits with a tenth of the warm fits' loss and a pose of their own (0.3 rad everywhere)."""

    def fit(self, people, K, origin, options=None):
        fits = super().fit(people, K, origin, options)
        out = []
        for f in fits:
            params = f.params.copy()
            params.pose = np.full_like(params.pose, 0.3)
            out.append(dataclasses.replace(f, params=params, quality=dataclasses.replace(f.quality, final_loss=0.05)))
        return out


def _run(path: FrameFitter, frames: int) -> None:
    for k in range(frames):
        frame = SimpleNamespace(stamp_ns=k * NS, camera=SimpleNamespace(K=np.eye(3)))
        people = path.tracker.assign([observation(4, 0.1 * k)], frame.stamp_ns)
        path.fit_observed(FrameFits(frame, people, [], np.zeros(3)))


def test_a_background_refresh_is_taken_frames_later_and_starts_the_next_warm_solve():
    """Without `refresh_second_start`: the better cold fit becomes the track's last fit."""
    cold, warm = StubFitter(), StubFitter()
    background = InProcessBackground(BetterColdFits())
    core = load_config(overrides={"tracking": {"refresh_frames": 3, "refresh_apply_frames": 2,
                                               "refresh_second_start": False}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm, background=background)
    _run(path, 8)
    # frame 0: new track, cold inline; frame 3: refresh sent to the background, the frame output warm;
    # taken before frame 6's warm solve (2 fitted frames after its own), which starts from it; frame 6
    # sends the next refresh
    assert len(cold.calls) == 1 and len(warm.calls) == 7
    assert len(background.jobs) == 2 and background.taken == [0]
    assert background.jobs[0][0].hypothesis is not None, "the warm start is one of the cold fit's hypotheses"
    warm_poses = [float(call[0].init.pose.mean()) for call in warm.calls]  # frames 1-7
    assert warm_poses == [0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 0.3], warm_poses
    fits = path.tracker.stats.fits
    assert fits["refresh"] == 2 and fits["refresh_background"] == 2 and fits["refreshed"] == 1
    assert fits["warm"] == 7 and fits["cold"] == 1


class LossByPose(StubFitter):
    """Warm fits whose final loss follows their start's mean pose angle: `sign` +1, the 0.3 rad start of a
    `BetterColdFits` refresh has the higher loss; -1, the lower."""

    def __init__(self, sign: float) -> None:
        super().__init__()
        self.sign = sign

    def fit(self, people, K, origin, options=None):
        fits = super().fit(people, K, origin, options)
        return [dataclasses.replace(f, quality=dataclasses.replace(
            f.quality, final_loss=1.0 + self.sign * float(p.init.pose.mean()))) for f, p in zip(fits, people)]


@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_a_background_refresh_is_a_second_warm_start_kept_by_its_loss(sign):
    """A refresh's cold fit is 2 fitted frames old when it is taken; with `refresh_second_start` (the
    default) it is not the track's last fit but a second start of that frame's warm solve, beside the
    usual one, and the lower final loss of the two is kept (the same profile on the same data)."""
    cold, warm = StubFitter(), LossByPose(sign)
    background = InProcessBackground(BetterColdFits())
    core = load_config(overrides={"tracking": {"refresh_frames": 3, "refresh_apply_frames": 2}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm, background=background)
    _run(path, 8)
    starts = [[float(p.init.pose.mean()) for p in call] for call in warm.calls]  # frames 1-7
    assert starts[:5] == [[0.0]] * 5 and starts[5] == [0.0, 0.3], starts
    won = sign < 0
    assert starts[6] == ([0.3] if won else [0.0]), starts
    fits = path.tracker.stats.fits
    assert fits["refresh_second_starts"] == 1 and fits["refreshed_second_start"] == int(won)
    assert fits["refreshed"] == 0 and fits["warm"] == 7 and fits["cold"] == 1


def test_a_background_refresh_no_better_than_its_warm_fit_is_not_taken():
    cold, warm = StubFitter(), StubFitter()
    background = InProcessBackground(StubFitter())  # the same loss as the warm fits
    core = load_config(overrides={"tracking": {"refresh_frames": 3, "refresh_apply_frames": 0}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm, background=background)
    _run(path, 6)
    assert background.taken == [0] and path.tracker.stats.fits["refreshed"] == 0
    assert "warm_start" in path.tracker.track(4).last_fit.flags


class LosesFrame2(StubFitter):
    """Warm fits, the `lost_call`-th of which (frame 2 by default) diverged: it lost its person."""

    def __init__(self, lost_call: int = 2) -> None:
        super().__init__()
        self.lost_call = lost_call

    def fit(self, people, K, origin, options=None):
        fits = super().fit(people, K, origin, options)
        if len(self.calls) == self.lost_call:
            fits = [dataclasses.replace(f, flags=set(f.flags) | {"diverged"}) for f in fits]
        return fits


@pytest.mark.parametrize("apply_frames", [0, 1])
def test_a_lost_warm_fit_is_output_flagged_and_refitted_cold_in_the_background(apply_frames):
    cold, warm = StubFitter(), LosesFrame2()
    background = InProcessBackground(BetterColdFits())
    core = load_config(overrides={"tracking": {"refresh_frames": 0, "lost_background": True,
                                               "lost_apply_frames": apply_frames}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm, background=background)
    outputs = []
    for k in range(6):
        frame = SimpleNamespace(stamp_ns=k * NS, camera=SimpleNamespace(K=np.eye(3)))
        people = path.tracker.assign([observation(4, 0.1 * k)], frame.stamp_ns)
        outputs.append(path.fit_observed(FrameFits(frame, people, [], np.zeros(3))).fits[0])
    # frame 0: new track, cold inline; frame 2's warm fit is lost: output flagged, its cold refit (no
    # refresh hypothesis) sent to the background and taken before the warm solve `apply_frames` fitted
    # frames later, which starts from it; the frames between start from the lost fit
    assert len(cold.calls) == 1 and len(warm.calls) == 5
    assert "lost" in outputs[2].flags and "warm_start" in outputs[2].flags
    assert not any("lost" in f.flags for k, f in enumerate(outputs) if k != 2)
    assert len(background.jobs) == 1 and background.taken == [0]
    assert background.jobs[0][0].hypothesis is None and background.jobs[0][0].predicted_pelvis is not None
    taken_at = 3 + apply_frames
    warm_poses = [float(call[0].init.pose.mean()) for call in warm.calls]  # frames 1-5
    assert warm_poses == [0.3 if k >= taken_at else 0.0 for k in range(1, 6)], warm_poses
    fits = path.tracker.stats.fits
    assert fits["lost"] == 1 and fits["lost_background"] == 1 and fits["lost_refitted"] == 1
    assert fits["cold"] == 1


def test_a_warm_fit_lost_while_its_refresh_runs_takes_the_refresh_instead_of_a_new_cold_fit():
    cold, warm = StubFitter(), LosesFrame2(lost_call=4)
    background = InProcessBackground(BetterColdFits())
    core = load_config(overrides={"tracking": {"refresh_frames": 3, "refresh_apply_frames": 3,
                                               "lost_background": True, "lost_apply_frames": 0}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm, background=background)
    _run(path, 7)
    # frame 3: refresh sent; frame 4's warm fit is lost: no cold fit of its own, the refresh is taken
    # before frame 5's warm solve (lost_apply_frames after it started, not refresh_apply_frames); frame 6
    # sends the next refresh
    assert len(cold.calls) == 1 and len(background.jobs) == 2 and background.taken == [0]
    warm_poses = [float(call[0].init.pose.mean()) for call in warm.calls]  # frames 1-6
    assert warm_poses == [0.0, 0.0, 0.0, 0.0, 0.3, 0.3], warm_poses
    fits = path.tracker.stats.fits
    assert fits["lost"] == 1 and fits["lost_background"] == 1 and fits["lost_refitted"] == 1
    assert fits["refreshed"] == 0


def test_a_lost_warm_fit_is_refitted_inline_without_lost_background():
    cold, warm = StubFitter(), LosesFrame2()
    core = load_config(overrides={"tracking": {"refresh_frames": 0}})
    background = InProcessBackground(BetterColdFits())
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm, background=background)
    _run(path, 4)
    assert len(cold.calls) == 2 and background.jobs == []  # frame 0 and frame 2's lost fit
    assert path.tracker.stats.fits["lost"] == 1 and path.tracker.stats.fits["lost_background"] == 0


def test_a_failed_background_process_leaves_the_refreshes_inline():
    cold, warm = StubFitter(), StubFitter()
    background = InProcessBackground(BetterColdFits())
    background.fail = True
    core = load_config(overrides={"tracking": {"refresh_frames": 3, "refresh_apply_frames": 0}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm, background=background)
    _run(path, 7)
    # frame 3's refresh went to the background, whose result failed at frame 4; frame 6's runs inline
    assert len(background.jobs) == 1 and not path.refreshes_in_background
    assert path.tracker.stats.fits["refresh_failed"] == 1
    assert len(cold.calls) == 2 and cold.calls[1][0].hypothesis is not None


def test_the_helper_process_fits_as_the_fitter_in_this_process(anny_model):
    """The process path end to end: config and people pickled over, the same fits back (deterministic),
    a job that fails there comes back as an error, and close ends the process."""
    config = load_config().fitting
    rng = np.random.default_rng(5)
    K = default_intrinsics()
    person = make_person(anny_model, rng, K, distance=4.0, yaw=0.4, n_points=200, point_noise=0.01,
                         keypoint_noise_px=2.0, person_id=0).observation
    here = Fitter(config, anny_model).fit([person], K)[0]
    background = BackgroundFitter(config, nice=5)
    try:
        assert background.wait_ready(90.0)
        job = background.submit([person], K, None, None)
        bad = background.submit([person], np.zeros(2), None, None)  # K of the wrong shape: fails there
        there = background.result(job, timeout_s=90.0)[0]
        with pytest.raises(BackgroundError, match="failed"):
            background.result(bad, timeout_s=90.0)
        assert background.alive
        background.submit([person], K, None, None)  # closed while it fits: the process ends quietly
    finally:
        background.close()
    assert not background.alive and background._proc.returncode == 0
    np.testing.assert_allclose(there.vertices, here.vertices, atol=1e-6)
    assert there.person_id == 0 and there.flags == here.flags


def test_the_helper_process_closed_before_it_is_ready_ends_quietly():
    """A run that ends while the process still loads its model (a short bag): no traceback, exit 0."""
    background = BackgroundFitter(load_config().fitting)
    background.close()
    assert not background.alive and background._proc.returncode == 0
