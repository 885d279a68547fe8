"""Message byte buffers as numpy arrays, whatever the runtime stores them as."""

from __future__ import annotations

from typing import Any

import numpy as np


def as_bytes(data: Any, error: type[Exception] = ValueError) -> np.ndarray:
    """A message's `data` as a flat uint8 array, without copying where the storage allows it.

    rosbags stores numpy arrays, rclpy array.array('B') (or bytes / lists when set by hand); all of these
    work. Anything else raises `error`.
    """
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    try:
        return np.frombuffer(data, dtype=np.uint8)  # bytes, bytearray, memoryview, array.array
    except TypeError:
        pass
    if isinstance(data, (list, tuple)):
        try:
            return np.asarray(data, dtype=np.uint8).reshape(-1)
        except (TypeError, ValueError, OverflowError) as e:
            raise error(f"data is not a list of bytes: {e}") from e
    raise error(f"data is not a byte buffer ({type(data).__name__})")
