"""CameraInfo <-> CameraModel, validation, binning/ROI, and projection/undistortion consistency."""

from __future__ import annotations

import numpy as np
import pytest

from msg_adapters.camera_info import CameraInfoError, camera_info_to_model, camera_model_to_msg
from msg_adapters.factory import RclpyFactory, RosbagsFactory, rclpy_available, to_plain
from smplify3d_ros.camera import project_points, undistort_pixels
from smplify3d_ros.types import CameraModel

needs_rclpy = pytest.mark.skipif(not rclpy_available(), reason="rclpy not installed")
FACTORIES = [pytest.param(RosbagsFactory(), id="rosbags"),
             pytest.param(RclpyFactory(), id="rclpy", marks=needs_rclpy)]
K = np.array([[600.0, 0.0, 320.5], [0.0, 610.0, 240.25], [0.0, 0.0, 1.0]])
MODELS = {
    "plumb_bob": [-0.28, 0.09, 0.0008, -0.0005, -0.012],
    "rational_polynomial": [0.4, -0.1, 0.0006, 0.0003, 0.02, 0.75, -0.05, 0.06],
    "equidistant": [-0.02, 0.004, -0.003, 0.0008],
}


def info_msg(factory=None, **fields):
    factory = factory or RosbagsFactory()
    values = {"width": 640, "height": 480, "k": K.ravel(), "distortion_model": "plumb_bob",
              "d": MODELS["plumb_bob"]}
    values.update(fields)
    return factory.make("sensor_msgs/msg/CameraInfo", header=factory.header(1.0, "cam"), **values)


@pytest.mark.parametrize("factory", FACTORIES)
@pytest.mark.parametrize("model", list(MODELS))
def test_camera_info_to_model(factory, model):
    cam = camera_info_to_model(info_msg(factory, distortion_model=model, d=MODELS[model]))
    np.testing.assert_array_equal(cam.K, K)
    assert (cam.width, cam.height, cam.distortion_model) == (640, 480, model)
    np.testing.assert_array_equal(cam.dist_coeffs, MODELS[model])
    assert cam.K.dtype == np.float64 and cam.has_distortion


@pytest.mark.parametrize("factory", FACTORIES)
def test_model_to_msg_roundtrip_and_projection_matrix(factory):
    cam = CameraModel(K=K, width=640, height=480, distortion_model="rational_polynomial",
                      dist_coeffs=np.array(MODELS["rational_polynomial"]))
    msg = camera_model_to_msg(cam, 5.5, "cam_optical", factory)
    assert msg.header.frame_id == "cam_optical" and msg.header.stamp.sec == 5
    np.testing.assert_array_equal(np.asarray(msg.r).reshape(3, 3), np.eye(3))
    np.testing.assert_array_equal(np.asarray(msg.p).reshape(3, 4), np.c_[K, np.zeros(3)])
    back = camera_info_to_model(msg)
    np.testing.assert_array_equal(back.K, K)
    np.testing.assert_array_equal(back.dist_coeffs, cam.dist_coeffs)
    assert back.distortion_model == "rational_polynomial"


@needs_rclpy
def test_model_to_msg_same_from_both_factories():
    cam = CameraModel(K=K, width=640, height=480, distortion_model="plumb_bob",
                      dist_coeffs=np.array(MODELS["plumb_bob"]))
    assert to_plain(camera_model_to_msg(cam, 1.0, "c", RclpyFactory())) == to_plain(
        camera_model_to_msg(cam, 1.0, "c", RosbagsFactory()))


def test_no_distortion_and_unknown_model_with_zero_coefficients():
    cam = camera_info_to_model(info_msg(distortion_model="", d=[]))
    assert not cam.has_distortion
    cam = camera_info_to_model(info_msg(distortion_model="weird", d=[0.0] * 5))
    assert not cam.has_distortion


def test_binning_and_roi_reduce_intrinsics():
    factory = RosbagsFactory()
    roi = factory.make("sensor_msgs/msg/RegionOfInterest", x_offset=100, y_offset=40, width=400, height=300)
    cam = camera_info_to_model(info_msg(factory, binning_x=2, binning_y=2, roi=roi))
    assert (cam.width, cam.height) == (200, 150)
    expected = [[300.0, 0, (320.5 - 100) / 2], [0, 305.0, (240.25 - 40) / 2], [0, 0, 1]]
    np.testing.assert_allclose(cam.K, expected)
    # A pixel seen in the full image lands at the reduced coordinates in the binned crop.
    p = np.array([[0.3, -0.2, 3.0]])
    full = camera_info_to_model(info_msg(factory))
    uv_full, uv_crop = project_points(p, full), project_points(p, cam)
    np.testing.assert_allclose(uv_crop, (uv_full - [100, 40]) / 2, atol=1e-9)


@pytest.mark.parametrize("fields,match", [
    ({"k": np.zeros(9)}, "fx = 0.0, fy = 0.0 must be > 0"),
    ({"k": np.r_[K.ravel()[:8], np.nan]}, "K must hold 9 finite values"),
    ({"width": 0}, "image size 0x480"),
    ({"height": 0}, "image size 640x0"),
    ({"d": [0.1, np.inf, 0, 0, 0]}, "distortion coefficients must be finite"),
    ({"distortion_model": "kannala", "d": [0.1, 0, 0, 0]}, "unsupported distortion model 'kannala'"),
    ({"distortion_model": "equidistant", "d": [0.1, 0.2]}, "takes .* coefficients, got 2"),
    ({"distortion_model": "plumb_bob", "d": [0.1, 0.2, 0.0, 0.0, 0.0, 0.3]}, "got 6"),
])
def test_invalid_camera_info(fields, match):
    with pytest.raises(CameraInfoError, match=match):
        camera_info_to_model(info_msg(**fields))


def test_roi_outside_image():
    factory = RosbagsFactory()
    roi = factory.make("sensor_msgs/msg/RegionOfInterest", x_offset=600, y_offset=0, width=100, height=10)
    with pytest.raises(CameraInfoError, match="roi .* lies outside"):
        camera_info_to_model(info_msg(factory, roi=roi))


@pytest.mark.parametrize("model", list(MODELS))
def test_undistort_inverts_project(model):
    cam = camera_info_to_model(info_msg(distortion_model=model, d=MODELS[model]))
    rng = np.random.default_rng(0)
    # Points over the whole image, corners included (strongest distortion).
    uv_ideal = np.c_[rng.uniform(0, 639, 400), rng.uniform(0, 479, 400)]
    uv_ideal = np.r_[uv_ideal, [[0, 0], [639, 0], [0, 479], [639, 479]]]
    rays = np.c_[(uv_ideal - K[:2, 2]) / np.diag(K)[:2], np.ones(len(uv_ideal))] * 4.0
    distorted = project_points(rays, cam)
    assert np.abs(distorted - uv_ideal).max() > 5.0  # the distortion is real
    back = undistort_pixels(distorted, cam)
    err = np.linalg.norm(back - uv_ideal, axis=1).max()
    assert err < 0.05, f"{model}: undistort(project(p)) is {err:.4f} px off"
    np.testing.assert_allclose(project_points(rays, cam, distort=False), uv_ideal, atol=1e-9)


@pytest.mark.parametrize("model", list(MODELS))
def test_undistort_reads_the_pixels_of_a_keypoint_array_in_place(model):
    """Keypoints are (P, 17, 3) u, v, score: their pixels, `keypoints[..., :2]`, are a strided view. The
    fisheye undistortion read such a view as packed pairs and gave the scores back as coordinates, so a
    fisheye camera lost every person's keypoints but the first."""
    cam = camera_info_to_model(info_msg(distortion_model=model, d=MODELS[model]))
    rng = np.random.default_rng(1)
    keypoints = np.concatenate([rng.uniform([50, 50], [590, 430], (2, 17, 2)), rng.uniform(0, 1, (2, 17, 1))], -1)
    view = keypoints[..., :2].reshape(-1, 2)
    assert not view.flags["C_CONTIGUOUS"]
    np.testing.assert_allclose(undistort_pixels(view, cam), undistort_pixels(view.copy(), cam), atol=1e-9)
