"""Image and CompressedImage <-> numpy: every encoding, padding, byte order, codecs, malformed input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from msg_adapters.factory import RclpyFactory, RosbagsFactory, rclpy_available, to_plain
from msg_adapters.image import (
    ImageError,
    compressed_to_numpy,
    image_to_numpy,
    numpy_to_compressed,
    numpy_to_image,
    to_rgb8,
)

needs_rclpy = pytest.mark.skipif(not rclpy_available(), reason="rclpy not installed")
FACTORIES = [pytest.param(RosbagsFactory(), id="rosbags"),
             pytest.param(RclpyFactory(), id="rclpy", marks=needs_rclpy)]
RNG = np.random.default_rng(0)
RGB = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)
ALPHA = RNG.integers(0, 256, (5, 7, 1), dtype=np.uint8)
MONO = RNG.integers(0, 256, (5, 7), dtype=np.uint8)
DEPTH = RNG.integers(0, 65536, (5, 7), dtype=np.uint16)


def raw_image(factory, encoding, pixels: np.ndarray, pad: int = 0, bigendian: bool = False):
    """An Image built by hand from channel-ordered pixels, rows padded with `pad` garbage bytes."""
    h, w = pixels.shape[:2]
    if pixels.dtype == np.uint16:
        pixels = pixels.astype(">u2" if bigendian else "<u2")
    rows = np.ascontiguousarray(pixels).view(np.uint8).reshape(h, -1)
    data = np.concatenate([rows, np.full((h, pad), 0xEE, np.uint8)], axis=1)
    return factory.make("sensor_msgs/msg/Image", header=factory.header(2.0, "cam"), height=h, width=w,
                        encoding=encoding, is_bigendian=bigendian, step=data.shape[1], data=data.tobytes())


CASES = {  # encoding: (pixels as stored in the message, expected array)
    "rgb8": (RGB, RGB),
    "bgr8": (RGB[:, :, ::-1], RGB),
    "rgba8": (np.concatenate([RGB, ALPHA], 2), RGB),
    "bgra8": (np.concatenate([RGB[:, :, ::-1], ALPHA], 2), RGB),
    "mono8": (MONO, MONO),
    "8UC1": (MONO, MONO),
    "mono16": (DEPTH, DEPTH),
    "16UC1": (DEPTH, DEPTH),
}


@pytest.mark.parametrize("factory", FACTORIES)
@pytest.mark.parametrize("encoding", list(CASES))
@pytest.mark.parametrize("pad", [0, 5])
def test_image_to_numpy_all_encodings_with_step_padding(factory, encoding, pad):
    stored, expected = CASES[encoding]
    out = image_to_numpy(raw_image(factory, encoding, stored, pad=pad))
    assert out.dtype == expected.dtype and out.shape == expected.shape
    np.testing.assert_array_equal(out, expected)
    out[0, 0] = 0  # owned and writable
    assert out.flags.writeable and out.flags.c_contiguous


@pytest.mark.parametrize("encoding", ["16UC1", "mono16"])
def test_big_endian_16bit(encoding):
    out = image_to_numpy(raw_image(RosbagsFactory(), encoding, DEPTH, pad=3, bigendian=True))
    np.testing.assert_array_equal(out, DEPTH)
    assert out.dtype == np.dtype("=u2")


@pytest.mark.parametrize("factory", FACTORIES)
@pytest.mark.parametrize("encoding", list(CASES))
def test_numpy_to_image_roundtrip(factory, encoding):
    _, array = CASES[encoding]
    msg = numpy_to_image(array, encoding, 3.0, "cam", factory)
    assert msg.encoding == encoding and msg.header.frame_id == "cam" and msg.is_bigendian == 0
    assert msg.step == msg.width * len(bytes(msg.data)) // (msg.width * msg.height)
    np.testing.assert_array_equal(image_to_numpy(msg), array)


@needs_rclpy
def test_numpy_to_image_same_message_from_both_factories():
    a = numpy_to_image(RGB, "bgr8", 1.0, "c", RclpyFactory())
    b = numpy_to_image(RGB, "bgr8", 1.0, "c", RosbagsFactory())
    assert to_plain(a) == to_plain(b)
    assert bytes(a.data)[:3] == bytes(RGB[0, 0, ::-1])  # really written BGR


def test_numpy_to_image_keeps_given_alpha():
    rgba = np.concatenate([RGB, ALPHA], 2)
    msg = numpy_to_image(rgba, "bgra8", 0.0, "c", RosbagsFactory())
    stored = np.asarray(msg.data).reshape(5, 7, 4)
    np.testing.assert_array_equal(stored[:, :, 3:], ALPHA)
    np.testing.assert_array_equal(stored[:, :, :3], RGB[:, :, ::-1])
    opaque = numpy_to_image(RGB, "rgba8", 0.0, "c", RosbagsFactory())
    assert (np.asarray(opaque.data).reshape(5, 7, 4)[:, :, 3] == 255).all()


@pytest.mark.parametrize("field,value,match", [
    ("encoding", "yuv422", "unsupported image encoding 'yuv422'"),
    ("width", 0, "zero size"),
    ("height", 0, "zero size"),
    ("step", 20, "step 20 is shorter than a row"),
    ("data", b"\x00" * 104, "data has 104 bytes, expected step 21 x height 5 = 105"),
    ("data", 3.5, "data is not a byte buffer"),
])
def test_malformed_images(field, value, match):
    msg = raw_image(RosbagsFactory(), "rgb8", RGB)
    setattr(msg, field, value)
    with pytest.raises(ImageError, match=match):
        image_to_numpy(msg)


@pytest.mark.parametrize("array,encoding,match", [
    (RGB, "mono8", r"needs an \(H, W\) array"),
    (MONO, "rgb8", r"needs an \(H, W, 3\) RGB array"),
    (RGB.astype(np.float32), "rgb8", "needs a uint8 array"),
    (DEPTH.astype(np.int32), "16UC1", "needs a uint16 array"),
    (np.zeros((0, 4, 3), np.uint8), "rgb8", "zero size"),
    (RGB, "jpeg", "unsupported image encoding"),
])
def test_numpy_to_image_rejects_mismatches(array, encoding, match):
    with pytest.raises(ImageError, match=match):
        numpy_to_image(array, encoding, 0.0, "c", RosbagsFactory())


def test_to_rgb8():
    np.testing.assert_array_equal(to_rgb8(MONO), np.repeat(MONO[:, :, None], 3, 2))
    np.testing.assert_array_equal(to_rgb8(np.concatenate([RGB, ALPHA], 2)), RGB)
    depth = np.array([[0, 1000], [2000, 4000]], np.uint16)
    np.testing.assert_array_equal(to_rgb8(depth)[:, :, 0], [[0, 64], [128, 255]])
    np.testing.assert_array_equal(to_rgb8(np.array([[0.0, 0.5, 2.0]]))[0, :, 1], [0, 128, 255])
    assert to_rgb8(np.zeros((2, 2), np.uint16)).max() == 0
    with pytest.raises(ImageError, match="dtype int64"):
        to_rgb8(np.zeros((2, 2), np.int64))


# ---------------------------------------------------------------------------------------------- compressed
_GX, _GY = np.meshgrid(np.linspace(0, 255, 32), np.linspace(0, 255, 24))
SMOOTH = np.stack([_GX, _GY, np.full((24, 32), 90.0)], axis=2).astype(np.uint8)  # jpeg stays close


@pytest.mark.parametrize("factory", FACTORIES)
def test_compressed_roundtrips(factory):
    jpeg = numpy_to_compressed(SMOOTH, 1.0, "cam", factory, fmt="jpeg", quality=95)
    assert jpeg.format == "rgb8; jpeg compressed bgr8"
    out = compressed_to_numpy(jpeg)
    assert out.shape == SMOOTH.shape and np.abs(out.astype(int) - SMOOTH).mean() < 2.0
    assert out[0, -1, 0] > 200 and out[0, -1, 2] < 120  # red stays red: channel order right
    png = numpy_to_compressed(RGB, 1.0, "cam", factory, fmt="png")
    np.testing.assert_array_equal(compressed_to_numpy(png), RGB)
    np.testing.assert_array_equal(compressed_to_numpy(numpy_to_compressed(MONO, 1.0, "c", factory, "png")),
                                  MONO)
    depth = numpy_to_compressed(DEPTH, 1.0, "c", factory, "png")
    assert depth.format == "mono16; png compressed mono16"
    out16 = compressed_to_numpy(depth)
    assert out16.dtype == np.uint16
    np.testing.assert_array_equal(out16, DEPTH)


def _compressed(data: bytes, fmt: str):
    return RosbagsFactory().make("sensor_msgs/msg/CompressedImage", format=fmt, data=data)


def _png_bytes(bgr: np.ndarray) -> bytes:
    return cv2.imencode(".png", bgr)[1].tobytes()


@pytest.mark.parametrize("fmt", ["png", "PNG", "bgr8; png compressed bgr8", "rgb8; png compressed bgr8", ""])
def test_format_strings_of_bgr_payloads(fmt):
    msg = _compressed(_png_bytes(RGB[:, :, ::-1].copy()), fmt)
    np.testing.assert_array_equal(compressed_to_numpy(msg), RGB)


def test_payload_stored_in_rgb_order_is_not_swapped():
    msg = _compressed(_png_bytes(RGB), "rgb8; png compressed rgb8")
    np.testing.assert_array_equal(compressed_to_numpy(msg), RGB)


def test_jpeg_magic_sniffed_without_format():
    data = cv2.imencode(".jpg", SMOOTH[:, :, ::-1].copy(), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    assert np.abs(compressed_to_numpy(_compressed(data, "")).astype(int) - SMOOTH).mean() < 2.0


def test_compressed_depth_png_with_config_header():
    header = np.array([0], "<i4").tobytes() + np.array([0.0, 0.0], "<f4").tobytes()
    data = header + cv2.imencode(".png", DEPTH)[1].tobytes()
    np.testing.assert_array_equal(compressed_to_numpy(_compressed(data, "16UC1; compressedDepth png")), DEPTH)


@pytest.mark.parametrize("data,fmt,match", [
    (b"", "jpeg", "has no data"),
    (b"\x00" * 64, "jpeg", "could not decode 64 bytes as jpeg"),
    (b"\x00" * 64, "", "neither jpeg nor png"),
    (b"\x00" * 64, "tiff", "unsupported compressed image format 'tiff'"),
    (b"\x00" * 64, "32FC1; compressedDepth png", "unsupported compressedDepth format"),
    (b"\x00" * 64, "16UC1; compressedDepth rvl", "unsupported compressedDepth format"),
])
def test_malformed_compressed(data, fmt, match):
    with pytest.raises(ImageError, match=match):
        compressed_to_numpy(_compressed(data, fmt))


@pytest.mark.parametrize("array,fmt,match", [
    (DEPTH, "jpeg", "cannot compress a uint16 array"),
    (RGB, "webp", "unsupported compressed image format"),
    (np.zeros((0, 3, 3), np.uint8), "png", "zero size"),
])
def test_numpy_to_compressed_rejects(array, fmt, match):
    with pytest.raises(ImageError, match=match):
        numpy_to_compressed(array, 0.0, "c", RosbagsFactory(), fmt=fmt)
