"""sensor_msgs/Image and sensor_msgs/CompressedImage <-> numpy.

Array conventions, the same both ways: colour images are (H, W, 3) uint8 RGB whatever the message's
channel order (rgb8, bgr8, rgba8, bgra8; alpha is dropped on reading), mono8 is (H, W) uint8, 16-bit
images (mono16, 16UC1) are (H, W) uint16. Arrays returned are owned copies, safe to draw on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from msg_adapters._buffer import as_bytes
from msg_adapters.factory import MessageFactory, resolve_factory


class ImageError(ValueError):
    """An image message this module cannot interpret; the message says what is wrong."""


@dataclass(frozen=True)
class _Encoding:
    channels: int
    dtype: np.dtype
    to_rgb: int | None  # cv2 colour conversion to RGB, None when already RGB or single-channel


ENCODINGS: dict[str, _Encoding] = {
    "rgb8": _Encoding(3, np.dtype(np.uint8), None),
    "bgr8": _Encoding(3, np.dtype(np.uint8), cv2.COLOR_BGR2RGB),
    "rgba8": _Encoding(4, np.dtype(np.uint8), cv2.COLOR_RGBA2RGB),
    "bgra8": _Encoding(4, np.dtype(np.uint8), cv2.COLOR_BGRA2RGB),
    "mono8": _Encoding(1, np.dtype(np.uint8), None),
    "8UC1": _Encoding(1, np.dtype(np.uint8), None),
    "mono16": _Encoding(1, np.dtype(np.uint16), None),
    "16UC1": _Encoding(1, np.dtype(np.uint16), None),
}


def _encoding(name: str) -> _Encoding:
    enc = ENCODINGS.get(str(name))
    if enc is None:
        raise ImageError(f"unsupported image encoding {name!r}; supported: {', '.join(ENCODINGS)}")
    return enc


def image_to_numpy(msg: Any) -> np.ndarray:
    """sensor_msgs/Image -> RGB uint8 (H, W, 3), or (H, W) uint8 / uint16 for mono and 16-bit encodings.

    Handles `step` padding and big-endian 16-bit data. Raises ImageError for an unknown encoding, a zero
    size, a `step` shorter than a row, or data shorter than step x height.
    """
    enc = _encoding(msg.encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise ImageError(f"image has zero size ({width}x{height})")
    row_bytes = width * enc.channels * enc.dtype.itemsize
    if step < row_bytes:
        raise ImageError(f"step {step} is shorter than a row of {width} {msg.encoding} pixels ({row_bytes})")
    data = as_bytes(msg.data, ImageError)
    if len(data) < step * height:
        raise ImageError(
            f"data has {len(data)} bytes, expected step {step} x height {height} = {step * height}"
        )
    rows = data[: step * height].reshape(height, step)[:, :row_bytes]
    dtype = enc.dtype.newbyteorder(">" if msg.is_bigendian else "<") if enc.dtype.itemsize > 1 else enc.dtype
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(height, width, enc.channels)
    if enc.channels == 1:
        return pixels[:, :, 0].astype(enc.dtype)  # native byte order, owned
    if enc.to_rgb is None:
        return pixels.copy()
    return cv2.cvtColor(pixels, enc.to_rgb)


def to_rgb8(array: np.ndarray) -> np.ndarray:
    """Any image array of this module -> (H, W, 3) uint8 RGB, for drawing and overlays.

    Mono uint8 is replicated to three channels; 16-bit images are scaled so their maximum maps to 255
    (depth images in mm would be black otherwise); float images are taken as [0, 1]; RGBA drops alpha.
    """
    a = np.asarray(array)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.dtype == np.uint16:
        peak = int(a.max()) if a.size else 0
        a = (a.astype(np.float32) * (255.0 / peak)).round().astype(np.uint8) if peak else np.zeros_like(
            a, np.uint8)
    elif a.dtype.kind == "f":
        a = (np.nan_to_num(np.clip(a, 0.0, 1.0)) * 255.0).round().astype(np.uint8)
    elif a.dtype != np.uint8:
        raise ImageError(f"cannot show an image of dtype {a.dtype} as rgb8")
    if a.ndim == 2:
        return np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim == 3 and a.shape[2] in (3, 4):
        return np.ascontiguousarray(a[:, :, :3])
    raise ImageError(f"cannot show an array of shape {a.shape} as an image")


def numpy_to_image(
    array: np.ndarray, encoding: str, stamp: Any, frame_id: str, factory: MessageFactory | None = None
) -> Any:
    """The inverse of `image_to_numpy`: an RGB (H, W, 3) array (or RGBA (H, W, 4) for rgba8/bgra8), or
    (H, W) uint8 / uint16 for mono encodings -> sensor_msgs/Image, little-endian, no row padding."""
    factory = resolve_factory(factory)
    enc = _encoding(encoding)
    a = np.asarray(array)
    if a.dtype != enc.dtype:
        raise ImageError(f"{encoding} needs a {enc.dtype} array, got {a.dtype}")
    if enc.channels == 1:
        if a.ndim == 3 and a.shape[2] == 1:
            a = a[:, :, 0]
        if a.ndim != 2:
            raise ImageError(f"{encoding} needs an (H, W) array, got shape {a.shape}")
        pixels = a.astype(enc.dtype.newbyteorder("<"))
    else:
        if a.ndim != 3 or a.shape[2] not in (3, 4):
            raise ImageError(f"{encoding} needs an (H, W, 3) RGB array, got shape {a.shape}")
        rgb = np.ascontiguousarray(a[:, :, :3])
        if encoding == "rgb8":
            pixels = rgb
        elif encoding == "bgr8":
            pixels = rgb[:, :, ::-1]
        else:
            alpha = a[:, :, 3:] if a.shape[2] == 4 else np.full(a.shape[:2] + (1,), 255, np.uint8)
            pixels = np.concatenate([rgb if encoding == "rgba8" else rgb[:, :, ::-1], alpha], axis=2)
    height, width = pixels.shape[:2]
    if height == 0 or width == 0:
        raise ImageError(f"image has zero size ({width}x{height})")
    return factory.make(
        "sensor_msgs/msg/Image",
        header=factory.header(stamp, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=False,
        step=width * enc.channels * enc.dtype.itemsize,
        data=np.ascontiguousarray(pixels).tobytes(),
    )


# ------------------------------------------------------------------------------------------ compressed
_COMPRESSED_DEPTH_HEADER = 12  # compressed_depth_image_transport's ConfigHeader: int32 format, 2 x float32


def _codec(fmt: str, data: np.ndarray) -> str:
    """'jpeg' or 'png' from a CompressedImage format string, or from the data's magic bytes if empty."""
    text = fmt.lower()
    if "jpeg" in text or "jpg" in text:
        return "jpeg"
    if "png" in text:
        return "png"
    if text.strip() == "":
        if data[:3].tobytes() == b"\xff\xd8\xff":
            return "jpeg"
        if data[:8].tobytes() == b"\x89PNG\r\n\x1a\n":
            return "png"
        raise ImageError("compressed image has an empty format and is neither jpeg nor png")
    raise ImageError(f"unsupported compressed image format {fmt!r}; supported: jpeg, png")


def compressed_to_numpy(msg: Any) -> np.ndarray:
    """sensor_msgs/CompressedImage (jpeg or png) -> the arrays `image_to_numpy` returns.

    Understands image_transport's format strings ("jpeg", "rgb8; jpeg compressed bgr8",
    "mono16; png compressed mono16") and compressed_depth_image_transport's 16UC1 PNG
    ("16UC1; compressedDepth png"). Colour images come back RGB.
    """
    fmt = str(msg.format)
    data = as_bytes(msg.data, ImageError)
    if len(data) == 0:
        raise ImageError(f"compressed image ({fmt!r}) has no data")
    text = fmt.lower()
    if "compresseddepth" in text:
        if not text.startswith("16uc1") or "png" not in text:
            raise ImageError(f"unsupported compressedDepth format {fmt!r}; supported: 16UC1 png")
        data = data[_COMPRESSED_DEPTH_HEADER:]
    codec = _codec(fmt, data)
    decoded = cv2.imdecode(np.ascontiguousarray(data), cv2.IMREAD_UNCHANGED)
    if decoded is None or decoded.size == 0:
        raise ImageError(f"could not decode {len(data)} bytes as {codec} (format {fmt!r})")
    if decoded.ndim == 2:
        return decoded
    # cv2 decodes to BGR(A) unless the producer compressed RGB-ordered bytes ("... compressed rgb8").
    stored_rgb = "compressed rgb" in text
    if decoded.shape[2] == 4:
        return cv2.cvtColor(decoded, cv2.COLOR_RGBA2RGB if stored_rgb else cv2.COLOR_BGRA2RGB)
    return decoded.copy() if stored_rgb else cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)


def numpy_to_compressed(
    array: np.ndarray,
    stamp: Any,
    frame_id: str,
    factory: MessageFactory | None = None,
    fmt: str = "jpeg",
    quality: int = 90,
) -> Any:
    """RGB (H, W, 3) uint8, (H, W) uint8 or (H, W) uint16 (png only) -> sensor_msgs/CompressedImage.

    The format string follows image_transport ("rgb8; jpeg compressed bgr8"), so standard decoders and
    `compressed_to_numpy` read it back.
    """
    factory = resolve_factory(factory)
    codec = fmt.lower().replace("jpg", "jpeg")
    if codec not in ("jpeg", "png"):
        raise ImageError(f"unsupported compressed image format {fmt!r}; supported: jpeg, png")
    a = np.asarray(array)
    if a.size == 0:
        raise ImageError(f"image has zero size {a.shape}")
    if a.ndim == 3 and a.shape[2] == 3 and a.dtype == np.uint8:
        src, encoding, stored = cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_RGB2BGR), "rgb8", "bgr8"
    elif a.ndim == 2 and a.dtype == np.uint8:
        src, encoding, stored = a, "mono8", "mono8"
    elif a.ndim == 2 and a.dtype == np.uint16 and codec == "png":
        src, encoding, stored = a, "mono16", "mono16"
    else:
        raise ImageError(f"cannot compress a {a.dtype} array of shape {a.shape} as {codec}")
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if codec == "jpeg" else []
    ok, buf = cv2.imencode(".jpg" if codec == "jpeg" else ".png", src, params)
    if not ok:
        raise ImageError(f"cv2 could not encode a {a.shape} image as {codec}")
    return factory.make(
        "sensor_msgs/msg/CompressedImage",
        header=factory.header(stamp, frame_id),
        format=f"{encoding}; {codec} compressed {stored}",
        data=buf.tobytes(),
    )
