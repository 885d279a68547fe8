"""The ~/bodies JSON document: writer, parser round trip, and one clear error per malformed input."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from msg_adapters.bodies import SCHEMA, BodiesError, bodies_json_to_params, fits_to_bodies_json
from msg_adapters.factory import RosbagsFactory
from smplify3d_ros.keypoints import COCO17_NAMES
from smplify3d_ros.types import BodyFit, BodyParams, FitQuality

JOINTS = ["pelvis", "left_hip", "right_hip", "spine"]


def make_fit(pid: int, chamfer: float = 0.02, flags=()) -> BodyFit:
    rng = np.random.default_rng(pid + 100)
    params = BodyParams("anny", rng.uniform(0, 1, 5), rng.normal(scale=0.3, size=(4, 3)),
                        rng.normal(size=3), rng.normal(size=3) + [0, 0, 5])
    quality = FitQuality(2.5, chamfer, 321, ["torso", "head"], False, 0.75)
    kp3d = rng.normal(size=(17, 3)).astype(np.float32)
    return BodyFit(pid, params, list(JOINTS), np.zeros((5, 3), np.float32), kp3d,
                   np.zeros((4, 3), np.float32), quality, set(flags))


def strict_loads(text):
    def no_constants(name):
        raise AssertionError(f"invalid JSON constant {name}")

    return json.loads(text, parse_constant=no_constants)


def test_document_content():
    fits = [make_fit(3, chamfer=float("nan"), flags={"image_only", "few_keypoints"}), make_fit(8)]
    stamp = RosbagsFactory().time(0.0)
    stamp.sec, stamp.nanosec = 1_700_000_000, 987_654_321
    doc = strict_loads(fits_to_bodies_json(fits, stamp, "cam"))
    assert (doc["schema"], doc["version"], doc["frame_id"]) == (SCHEMA, 1, "cam")
    assert doc["stamp"] == {"sec": 1_700_000_000, "nanosec": 987_654_321}  # exact
    b = doc["bodies"][0]
    assert b["id"] == 3 and b["model"] == "anny" and list(b["pose"]) == JOINTS
    assert b["quality"] == {"reprojection_px": 2.5, "chamfer_m": None, "num_points": 321,
                            "visible_parts": ["torso", "head"], "icp_converged": False, "final_loss": 0.75}
    assert b["flags"] == ["few_keypoints", "image_only"]
    assert list(b["joints3d"]) == list(COCO17_NAMES)
    np.testing.assert_allclose(b["joints3d"]["left_hip"], fits[0].keypoints3d[11], atol=1e-6)
    np.testing.assert_allclose(b["pose"]["right_hip"], fits[0].params.pose[2], atol=1e-6)
    assert [x["id"] for x in doc["bodies"]] == [3, 8]


def test_roundtrip_to_params():
    fits = [make_fit(3), make_fit(8)]
    stamp, frame, bodies = bodies_json_to_params(fits_to_bodies_json(fits, 12.5, "cam"), JOINTS)
    assert (stamp, frame, sorted(bodies)) == (12.5, "cam", [3, 8])
    for fit in fits:
        got = bodies[fit.person_id]
        assert got.model == "anny"
        for name in ("shape", "pose", "root_orient", "transl"):
            np.testing.assert_allclose(getattr(got, name), getattr(fit.params, name), atol=1e-6)
    empty = bodies_json_to_params(fits_to_bodies_json([], 1.0, "cam").encode(), JOINTS)
    assert empty == (1.0, "cam", {})


def test_partial_pose_and_float_stamp_accepted():
    doc = {"schema": SCHEMA, "version": 1, "stamp": 4.25, "frame_id": "cam", "bodies": [
        {"id": 1, "model": "smpl", "shape": [], "root_orient": [0, 0, 0], "transl": [0, 0, 3],
         "pose": {"spine": [0.1, 0.2, 0.3]}}]}
    stamp, _, bodies = bodies_json_to_params(json.dumps(doc), JOINTS)
    assert stamp == 4.25
    np.testing.assert_array_equal(bodies[1].pose, [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0.1, 0.2, 0.3]])
    assert bodies[1].shape.shape == (0,)


def test_writer_rejects_pose_name_mismatch():
    fit = make_fit(1)
    fit.joint_names = JOINTS[:3]
    with pytest.raises(ValueError, match="3 joint names for 4 pose rows"):
        fits_to_bodies_json([fit], 0.0, "cam")


VALID = json.loads(fits_to_bodies_json([make_fit(3)], 1.0, "cam"))


def _mutated(path, value):
    doc = copy.deepcopy(VALID)
    target = doc
    for key in path[:-1]:
        target = target[key]
    if value is KeyError:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return json.dumps(doc)


@pytest.mark.parametrize("text,match", [
    ("{not json", "not valid JSON"),
    ("[1, 2]", "must be a JSON object"),
    (_mutated(["schema"], "other"), "'schema' must be 'smplify3d_ros/bodies'"),
    (_mutated(["schema"], KeyError), "'schema' must be"),
    (_mutated(["version"], 2), "unsupported 'version' 2"),
    (_mutated(["version"], "1"), "unsupported 'version' '1'"),
    (_mutated(["stamp"], KeyError), "missing 'stamp'"),
    (_mutated(["stamp"], {"sec": 1, "nanosec": 2_000_000_000}), "'stamp' must be"),
    (_mutated(["stamp"], {"sec": 1.5, "nanosec": 0}), "'stamp' must be"),
    (_mutated(["frame_id"], 5), "'frame_id' must be a string"),
    (_mutated(["bodies"], {}), "'bodies' must be a list"),
    (_mutated(["bodies", 0], 7), r"bodies\[0\] must be an object"),
    (_mutated(["bodies", 0, "id"], True), r"bodies\[0\]: 'id' must be an integer"),
    (_mutated(["bodies", 0, "id"], KeyError), "'id' must be an integer, got None"),
    (_mutated(["bodies", 0, "transl"], KeyError), r"bodies\[0\] \(id 3\): missing 'transl'"),
    (_mutated(["bodies", 0, "model"], ""), "'model' must be a non-empty string"),
    (_mutated(["bodies", 0, "shape"], [0.5, "tall"]), "'shape' must be a list of finite numbers"),
    (_mutated(["bodies", 0, "root_orient"], [0.0, 1.0]), "'root_orient' must have 3 numbers, got 2"),
    (_mutated(["bodies", 0, "transl"], [0.0, None, 1.0]), "'transl' must be a list of finite numbers"),
    (_mutated(["bodies", 0, "pose"], [[0, 0, 0]]), "'pose' must map joint names"),
    (_mutated(["bodies", 0, "pose", "tail"], [0, 0, 0]), "unknown joint\\(s\\) in 'pose': tail"),
    (_mutated(["bodies", 0, "pose", "spine"], [0, 0]), "pose\\['spine'\\] must have 3 numbers"),
    (_mutated(["bodies", 0, "pose", "spine"], [0, True, 0]), "pose\\['spine'\\] must be a list of finite"),
    (json.dumps({**VALID, "bodies": VALID["bodies"] * 2}), r"bodies\[1\]: person id 3 appears twice"),
])
def test_malformed_documents(text, match):
    with pytest.raises(BodiesError, match=match):
        bodies_json_to_params(text, JOINTS)


def test_nan_token_in_numbers_is_rejected():
    text = json.dumps(VALID).replace('"transl": [', '"transl": [NaN, ', 1)
    assert "NaN" in text and len(json.loads(text)["bodies"][0]["transl"]) == 4
    with pytest.raises(BodiesError, match="'transl' must be a list of finite numbers"):
        bodies_json_to_params(text, JOINTS)
    text = json.dumps(VALID).replace('"root_orient": [', '"root_orient": [Infinity, ', 1)
    with pytest.raises(BodiesError, match="'root_orient' must be a list of finite numbers"):
        bodies_json_to_params(text, JOINTS)
    assert issubclass(BodiesError, ValueError)
