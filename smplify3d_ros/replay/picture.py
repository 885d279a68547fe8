"""The replay's picture: the fitted frame with the most people, nearest the middle of the recording,
drawn over the image beside a bird's-eye view of the bodies and the LiDAR scan."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smplify3d_ros.types import BodyFit, Frame


class PictureChooser:
    """Keeps the best frame offered so far (most people, then nearest `middle_ns`)."""

    def __init__(self, middle_ns: float) -> None:
        self.middle_ns = middle_ns
        self.best: tuple[tuple[int, float], Frame, list[BodyFit]] | None = None

    def offer(self, frame: Frame, fits: list[BodyFit], timestamp: int) -> None:
        key = (len(fits), -abs(timestamp - self.middle_ns))
        if self.best is None or key > self.best[0]:
            self.best = (key, frame, fits)

    def write(self, path: Path, faces: np.ndarray, suffix: str = "") -> bool:
        """Write the picture in the format of `suffix` (default: `path`'s, e.g. .png); False when no frame
        was fitted."""
        import cv2

        from smplify3d_ros.overlay import overlay_image, top_view

        if self.best is None:
            return False
        _, frame, fits = self.best
        image = overlay_image(frame, fits, faces)
        image = np.hstack([image, top_view(frame, fits, image.shape[0])])
        ok, encoded = cv2.imencode(suffix or path.suffix or ".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        if not ok:
            raise OSError(f"cannot encode a picture as {suffix or path.suffix!r}")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(encoded.tobytes())
        return True
