"""A constant-velocity Kalman filter of one person's pelvis: where the person is, where they go.

State x = [p, v] (3 + 3, camera frame, m and m/s); the process is p' = p + v dt with white
acceleration noise (`accel_sigma`), the measurement the fitted pelvis position (`position_sigma`; a fit
from the image alone measures its depth, along the camera's ray, only to `depth_sigma`: without it, a
person 8 m out whose image-only depth moved 23 cm in one frame got a 1.6 m/s velocity towards the
wall behind them, and their warm start 0.6 s later was 0.9 m too deep).
One filter per track: its prediction places the warm start, its velocity goes to the outputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class MotionFilter:
    accel_sigma: float  # m/s², unmodelled acceleration
    position_sigma: float  # m, measurement noise of a fitted position
    x: np.ndarray = field(default_factory=lambda: np.zeros(6))  # [p, v]
    P: np.ndarray = field(default_factory=lambda: np.eye(6))
    initialized: bool = False

    def _transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        F = np.eye(6)
        F[:3, 3:] = dt * np.eye(3)
        q = self.accel_sigma**2
        # discrete white-noise acceleration: Q = q [[dt^4/4, dt^3/2], [dt^3/2, dt^2]] per axis
        Q = np.zeros((6, 6))
        Q[:3, :3] = q * dt**4 / 4 * np.eye(3)
        Q[:3, 3:] = Q[3:, :3] = q * dt**3 / 2 * np.eye(3)
        Q[3:, 3:] = q * dt**2 * np.eye(3)
        return F, Q

    def predicted(self, dt: float) -> np.ndarray:
        """(3,) the position `dt` seconds after the last update (without changing the filter)."""
        return self.x[:3] + max(dt, 0.0) * self.x[3:]

    def update(self, position: np.ndarray, dt: float, depth_sigma: float | None = None) -> None:
        """Fold in a measured position `dt` seconds after the previous one; with `depth_sigma` (m), its
        component along the ray from the camera is that uncertain (the other two `position_sigma`)."""
        position = np.asarray(position, np.float64)
        R = self.position_sigma**2 * np.eye(3)
        if depth_sigma is not None:
            ray = position / max(float(np.linalg.norm(position)), 1e-9)
            R += (depth_sigma**2 - self.position_sigma**2) * np.outer(ray, ray)
        if not self.initialized:
            self.x = np.concatenate([position, np.zeros(3)])
            # unknown velocity: walking speeds are within a few m/s
            self.P = np.zeros((6, 6))
            self.P[:3, :3], self.P[3:, 3:] = R, np.eye(3)
            self.initialized = True
            return
        F, Q = self._transition(max(dt, 0.0))
        x, P = F @ self.x, F @ self.P @ F.T + Q
        H = np.hstack([np.eye(3), np.zeros((3, 3))])
        S = H @ P @ H.T + R
        gain = P @ H.T @ np.linalg.inv(S)
        self.x = x + gain @ (position - H @ x)
        self.P = (np.eye(6) - gain @ H) @ P

    @property
    def position(self) -> np.ndarray:
        return self.x[:3].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self.x[3:].copy()
