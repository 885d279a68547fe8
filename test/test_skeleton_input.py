"""Keypoints from hri_msgs/Skeleton2D (`keypoint_input: skeleton2d`): one skeleton per body and the tracked
list, joined per image stamp, read back through the canonical keypoint encoding unchanged."""

from __future__ import annotations

import numpy as np

from msg_adapters import RosbagsFactory, read_keypoints, write_keypoints
from msg_adapters.hri import BodyIds, ids_list_msg, skeleton2d_msg, skeletons_to_keypoints
from smplify3d_ros.runtime.sync import SkeletonAssembler

F = RosbagsFactory()
S = 1_000_000_000
T0 = 1_700_000_000 * S


def skeleton(stamp_ns: int, seed: int):
    rng = np.random.default_rng(seed)
    kp = np.concatenate([rng.uniform(0, 1, (17, 2)) * [640, 480], rng.uniform(0.3, 1, (17, 1))], axis=1)
    return kp, skeleton2d_msg(kp, 640, 480, stamp_ns, "cam", F)


def test_a_stamp_is_emitted_once_its_list_and_skeletons_are_in():
    sets = []
    asm = SkeletonAssembler(sets.append)
    _, a = skeleton(T0, 1)
    _, b = skeleton(T0, 2)
    asm.add_skeleton("b1", a)
    asm.add_tracked(ids_list_msg(["b1", "b2"], T0, "cam", F))
    assert sets == []
    asm.add_skeleton("b2", b)
    assert [(s.stamp_ns, sorted(s.skeletons), s.missing) for s in sets] == [(T0, ["b1", "b2"], [])]


def test_a_later_list_completes_an_older_stamp_with_what_it_has():
    sets = []
    asm = SkeletonAssembler(sets.append)
    asm.add_tracked(ids_list_msg(["b1", "b2"], T0, "cam", F))
    asm.add_skeleton("b1", skeleton(T0, 1)[1])
    asm.add_tracked(ids_list_msg([], T0 + S // 10, "cam", F))  # everybody left
    assert [(s.stamp_ns, sorted(s.skeletons), s.missing) for s in sets] == [(T0, ["b1"], ["b2"]),
                                                                           (T0 + S // 10, [], [])]
    assert asm.missing == 1 and asm.sets == 2


def test_waiting_is_bounded():
    asm = SkeletonAssembler(lambda s: None, max_pending=3)
    for k in range(10):
        asm.add_skeleton("b1", skeleton(T0 + k * S, k)[1])  # never listed
        asm.add_tracked(ids_list_msg(["b9"], T0 + k * S + 1, "cam", F))  # never complete
    assert len(asm._skeletons) <= 3 and len(asm._tracked) <= 3 and asm.unlisted == 7


def test_skeletons_read_back_through_the_keypoint_encoding():
    truth = {}
    skeletons = {}
    for bid, seed in (("b4", 1), ("b11", 2), ("67dd1", 3)):
        truth[bid], skeletons[bid] = skeleton(T0, seed)
    ids = BodyIds("b")
    kp, pids = skeletons_to_keypoints(skeletons, 640, 480, ids)
    assert pids.tolist() == [2**30, 11, 4], "sorted by body id; b<n> is person n, other ids numbered apart"
    for fmt in ("coco17", "rep155"):
        cloud = write_keypoints(kp, pids, T0, "cam", F, keypoint_format=fmt)
        back = read_keypoints(cloud, fmt)
        assert back.person_ids.tolist() == pids.tolist()
        for got, bid in zip(back.keypoints, ("67dd1", "b11", "b4"), strict=True):
            np.testing.assert_allclose(got, truth[bid], atol=1e-3)
    assert ids.person_id("67dd1") == pids[0], "stable"
