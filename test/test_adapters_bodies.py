"""The ~/bodies JSON document: writer, parser round trip, and one clear error per malformed input."""

from __future__ import annotations

import copy
import json
import re

import numpy as np
import pytest

from msg_adapters import bodies as bodies_module
from msg_adapters.bodies import (
    MAX_DOCUMENT_BYTES,
    SCHEMA,
    BodiesError,
    bodies_json_to_params,
    clip,
    fits_to_bodies_json,
)
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
    stamp, frame, bodies = bodies_json_to_params(fits_to_bodies_json(fits, 12.5, "cam"), JOINTS, shape_size=5)
    assert (stamp, frame, sorted(bodies)) == (12_500_000_000, "cam", [3, 8])
    for fit in fits:
        got = bodies[fit.person_id]
        assert got.model == "anny"
        for name in ("shape", "pose", "root_orient", "transl"):
            np.testing.assert_allclose(getattr(got, name), getattr(fit.params, name), atol=1e-6)
    empty = bodies_json_to_params(fits_to_bodies_json([], 1.0, "cam").encode(), JOINTS)
    assert empty == (1_000_000_000, "cam", {})


def test_partial_pose_and_float_stamp_accepted():
    doc = {"schema": SCHEMA, "version": 1, "stamp": 4.25, "frame_id": "cam", "bodies": [
        {"id": 1, "model": "smpl", "shape": [], "root_orient": [0, 0, 0], "transl": [0, 0, 3],
         "pose": {"spine": [0.1, 0.2, 0.3]}}]}
    stamp, _, bodies = bodies_json_to_params(json.dumps(doc), JOINTS)
    assert stamp == 4_250_000_000
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
    with pytest.raises(BodiesError, match=match) as excinfo:
        bodies_json_to_params(text, JOINTS)
    assert "\n" not in str(excinfo.value)


def test_nan_token_in_numbers_is_rejected():
    text = json.dumps(VALID).replace('"transl": [', '"transl": [NaN, ', 1)
    assert "NaN" in text and len(json.loads(text)["bodies"][0]["transl"]) == 4
    with pytest.raises(BodiesError, match="'transl' must be a list of finite numbers"):
        bodies_json_to_params(text, JOINTS)
    text = json.dumps(VALID).replace('"root_orient": [', '"root_orient": [Infinity, ', 1)
    with pytest.raises(BodiesError, match="'root_orient' must be a list of finite numbers"):
        bodies_json_to_params(text, JOINTS)
    assert issubclass(BodiesError, ValueError)


# -- hostile documents: bounded cost, bounded messages, plausible values ----------------------------------
def _doc_with(**changes) -> str:
    doc = copy.deepcopy(VALID)
    body = changes.pop("body", {})
    doc.update(changes)
    doc["bodies"][0].update(body)
    return json.dumps(doc)


def _error(text, **kwargs) -> str:
    with pytest.raises(BodiesError) as excinfo:
        bodies_json_to_params(text, JOINTS, **kwargs)
    message = str(excinfo.value)
    assert "\n" not in message and len(message) < 400, message[:500]
    return message


@pytest.mark.parametrize("opening,closing", [("[", "]"), ('{"a":', "}")])
@pytest.mark.parametrize("as_bytes", [False, True])
def test_deep_nesting_is_refused_before_json(opening, closing, as_bytes):
    """200,000 levels would make json.loads recurse past Python's limit (RecursionError)."""
    text = opening * 200_000 + "0" + closing * 200_000
    message = _error(text.encode() if as_bytes else text)
    assert message == "bodies document nests 200000 levels deep, more than 32"


def test_brackets_inside_strings_do_not_count():
    text = _doc_with(frame_id="[" * 200 + "\\\"{" * 10)
    assert bodies_json_to_params(text, JOINTS)[1] == "[" * 200 + "\\\"{" * 10


def test_recursion_and_memory_errors_from_json_become_bodies_errors(monkeypatch):
    """Should the depth check ever let a document through, json's own failures still are BodiesErrors."""
    monkeypatch.setattr(bodies_module, "MAX_DEPTH", 10**9)
    assert "not valid JSON" in _error("[" * 200_000 + "]" * 200_000)

    def no_memory(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(bodies_module.json, "loads", no_memory)
    assert "not valid JSON" in _error(json.dumps(VALID))


@pytest.mark.parametrize("as_bytes", [False, True])
def test_oversize_document_is_refused_unread(as_bytes):
    text = json.dumps(VALID) + " " * MAX_DOCUMENT_BYTES
    message = _error(text.encode() if as_bytes else text)
    assert message == f"bodies document has {len(text)} bytes, more than {MAX_DOCUMENT_BYTES}"
    multibyte = json.dumps({**VALID, "frame_id": "é" * 100}, ensure_ascii=False)
    multibyte += " " * (MAX_DOCUMENT_BYTES - len(multibyte))
    assert len(multibyte) <= MAX_DOCUMENT_BYTES < len(multibyte.encode())  # the limit is on UTF-8 bytes
    assert "more than" in _error(multibyte)


def test_document_just_under_the_limit_parses():
    text = json.dumps(VALID)
    text += " " * (MAX_DOCUMENT_BYTES - len(text))
    assert bodies_json_to_params(text, JOINTS)[1] == "cam"


@pytest.mark.parametrize("size,limit", [(300, None), (5_000_000, None), (10_000_000, None),
                                        (10_000_000, 64 * 1024 * 1024)])
def test_long_frame_id_gives_a_short_message(monkeypatch, size, limit):
    """A 10 MB frame_id is refused (by size, or with a raised size limit by length) and never quoted whole."""
    if limit:
        monkeypatch.setattr(bodies_module, "MAX_DOCUMENT_BYTES", limit)
    text = _doc_with(frame_id="x" * size)
    message = _error(text)
    if len(text) > bodies_module.MAX_DOCUMENT_BYTES:
        assert message.startswith("bodies document has")
    else:
        assert message.startswith(f"bodies document: 'frame_id' has {size} characters, more than 256: 'xxx")


def test_frame_id_of_256_characters_is_accepted():
    assert bodies_json_to_params(_doc_with(frame_id="f" * 256), JOINTS)[1] == "f" * 256


@pytest.mark.parametrize("changes,match", [
    ({"frame_id": list(range(100_000))}, r"'frame_id' must be a string, got \[0, 1, 2, 3, 4, 5, \.\.\.\]$"),
    ({"schema": "s" * 1_000_000}, "'schema' must be 'smplify3d_ros/bodies', got 'sss"),
    ({"version": 10**4000}, "unsupported 'version' 1000"),
    ({"stamp": "t" * 1_000_000}, "'stamp' must be .* got 'ttt"),
    ({"body": {"model": "m" * 65}}, "'model' must be a non-empty string of at most 64 characters"),
    ({"body": {"id": 2**31}}, r"bodies\[0\]: 'id' 2147483648 is outside the int32 range"),
    ({"body": {"id": -(2**31) - 1}}, "'id' -2147483649 is outside the int32 range"),
    ({"body": {"shape": ["tall"] * 1_000_000}}, r"'shape' must be a list of finite numbers, got \['tall', "),
    ({"body": {"pose": {f"joint{i}\n": [0, 0, 0] for i in range(10_000)}}},
     r"unknown joint\(s\) in 'pose': joint0\\n, joint1\\n, joint10\\n and 9997 more; known: pelvis"),
])
def test_quoted_user_text_is_clipped(changes, match):
    assert re.search(match, _error(_doc_with(**changes)))


@pytest.mark.parametrize("size", [0, 100])
def test_shape_length_must_match_the_model(size):
    text = _doc_with(body={"shape": [0.5] * size})
    assert _error(text, shape_size=5) == f"bodies[0] (id 3): 'shape' has {size} values, the body model has 5"
    assert len(bodies_json_to_params(text, JOINTS)[2][3].shape) == size  # without shape_size: any length


@pytest.mark.parametrize("body,match", [
    ({"transl": [0.0, 1e308, 0.0]}, r"'transl' values must be within \+-1000 m, got 1e\+308"),
    ({"transl": [10**400, 0, 0]}, r"'transl' values must be within \+-1000 m, got 1000000"),
    ({"transl": [-1000.5, 0, 0]}, r"'transl' values must be within \+-1000 m, got -1000.5"),
    ({"shape": [0.5, -10.5]}, r"'shape' values must be within \+-10, got -10.5"),
    ({"root_orient": [13.0, 0, 0]}, r"'root_orient' values must be within \+-12.5664 rad"),
    ({"root_orient": [9.0, 9.0, 0]}, "'root_orient' has an axis-angle norm of 12.7 rad, more than 4 pi"),
    ({"pose": {"spine": [0, 9.0, -9.0]}}, r"pose\['spine'\] has an axis-angle norm of 12.7 rad"),
])
def test_implausible_values_are_refused(body, match):
    assert re.search(match, _error(_doc_with(body=body)))


def test_plausible_extremes_are_accepted():
    body = {"transl": [1000.0, -1000, 0], "shape": [10, -10.0], "root_orient": [12.5, 0, 0],
            "pose": {"spine": [0.0, 8.8, -8.8]}}
    params = bodies_json_to_params(_doc_with(body=body), JOINTS)[2][3]
    np.testing.assert_array_equal(params.transl, [1000, -1000, 0])


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_non_finite_pose_values_are_refused(token):
    text = json.dumps(VALID, separators=(",", ":")).replace('"spine":[', f'"spine":[{token},', 1)
    assert token in text
    assert "pose['spine'] must be a list of finite numbers" in _error(text)


def test_huge_integer_and_bad_utf8_are_bodies_errors():
    compact = json.dumps(VALID, separators=(",", ":"))
    assert "not valid JSON" in _error(compact.replace('"version":1', '"version":' + "9" * 5000))
    assert "not valid UTF-8" in _error(json.dumps(VALID).encode().replace(b'"cam"', b'"\xff\xfe"'))
    assert "must be str or bytes, got dict" in _error(VALID)


@pytest.mark.parametrize("stamp,ns", [
    ({"sec": 1_700_000_000, "nanosec": 123_456_789}, 1_700_000_000_123_456_789),
    ({"sec": -5, "nanosec": 999_999_999}, -4_000_000_001),
    ({"sec": 2**31 - 1, "nanosec": 999_999_999}, (2**31 - 1) * 10**9 + 999_999_999),
    (4.25, 4_250_000_000),
    (1_700_000_000.5, 1_700_000_000_500_000_000),
    (0.1, 100_000_000),
    (7, 7_000_000_000),
    (-1.5, -1_500_000_000),
])
def test_stamps_are_exact_integer_nanoseconds(stamp, ns):
    got = bodies_json_to_params(_doc_with(stamp=stamp), JOINTS)[0]
    assert type(got) is int and got == ns


@pytest.mark.parametrize("stamp", [{"sec": 2**31, "nanosec": 0}, {"sec": 1, "nanosec": -1}, 2.0**31, -1e300,
                                   {"sec": 1, "nanosec": 0, "extra": 1}, True])
def test_stamps_out_of_range_are_refused(stamp):
    assert "'stamp' must be" in _error(_doc_with(stamp=stamp))


def test_writer_takes_integer_nanoseconds_exactly():
    ns = 1_700_000_000_123_456_789
    doc = strict_loads(fits_to_bodies_json([make_fit(3)], ns, "cam"))
    assert doc["stamp"] == {"sec": 1_700_000_000, "nanosec": 123_456_789}
    assert bodies_json_to_params(fits_to_bodies_json([], np.int64(ns), "cam"), JOINTS)[0] == ns
    with pytest.raises(ValueError, match="int32 seconds"):
        fits_to_bodies_json([], 2**31 * 10**9, "cam")


def test_clip():
    assert clip("short") == "short"
    assert clip("x" * 1000) == "x" * 100 + "... (1000 characters)"
    assert clip("a\nb\r", n=10) == "a\\nb\\r"
    assert clip(12345, n=3) == "123... (5 characters)"
