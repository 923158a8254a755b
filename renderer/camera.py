"""Deterministic cameras that frame a model's bounds, and the matching CPU projection.

Matrices are row-major numpy (``clip = M @ [x, y, z, 1]``) and produce Vulkan clip space:
y points *down* the image after the viewport, depth is 0..1. The projection flips y so the
model's +Y is up in the picture. :func:`project_points` applies exactly the transform the
GPU applies (viewport included), so silhouettes can be compared with CPU projections.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

DEFAULT_VIEW = (-0.6, -0.45, -1.0)  # looking from front-right-above towards -Z, a 3/4 view
DEFAULT_FOV_DEG = 40.0


@dataclass(frozen=True)
class Camera:
    """A perspective camera: eye, target, vertical field of view, clip planes, image size."""

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_y_deg: float
    near: float
    far: float
    width: int
    height: int

    # computed once per camera (the fields are frozen): a render reads them a few times, the
    # silhouette check once per projection
    @cached_property
    def view(self) -> np.ndarray:
        return look_at(self.eye, self.target, self.up)

    @cached_property
    def proj(self) -> np.ndarray:
        return perspective(self.fov_y_deg, self.width / self.height, self.near, self.far)

    @cached_property
    def view_proj(self) -> np.ndarray:
        return self.proj @ self.view

    def pixel_size_at(self, distance: float) -> float:
        """Model units covered by one pixel at ``distance`` from the eye (image centre)."""
        return 2.0 * distance * np.tan(np.radians(self.fov_y_deg) / 2.0) / self.height


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """A right-handed view matrix (camera looks down -Z)."""
    f = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(eye, np.float64)
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """A Vulkan perspective projection (depth 0..1, y flipped so +Y is up in the image)."""
    t = 1.0 / np.tan(np.radians(fov_y_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0] = t / aspect
    m[1, 1] = -t
    m[2, 2] = far / (near - far)
    m[2, 3] = near * far / (near - far)
    m[3, 2] = -1.0
    return m


def _up_for(direction: np.ndarray) -> np.ndarray:
    d = direction / np.linalg.norm(direction)
    return np.array([0.0, 0.0, 1.0]) if abs(d[1]) > 0.99 else np.array([0.0, 1.0, 0.0])


def fit_camera(center: np.ndarray, radius: float, view_dir: tuple[float, float, float] | np.ndarray
               = DEFAULT_VIEW, width: int = 256, height: int = 256, fov_y_deg: float = DEFAULT_FOV_DEG,
               margin: float = 1.05, distance: float | None = None) -> Camera:
    """A camera looking along ``view_dir`` at the bounding sphere (center, radius).

    Without ``distance`` the whole sphere fits the smaller image dimension (times ``margin``).
    """
    c = np.asarray(center, np.float64)
    d = np.asarray(view_dir, np.float64)
    d = d / np.linalg.norm(d)
    r = max(float(radius), 1e-9)
    half = np.radians(fov_y_deg) / 2.0
    if width < height:  # the horizontal half-angle is the smaller one
        half = np.arctan(np.tan(half) * width / height)
    if distance is None:
        distance = r * margin / np.sin(half)
    near = max(distance - 2.0 * r, distance * 1e-3, 1e-9)
    far = distance + 2.0 * r
    return Camera(eye=c - d * distance, target=c, up=_up_for(d), fov_y_deg=fov_y_deg,
                  near=near, far=far, width=width, height=height)


def project_points(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N, 2) of ``points`` (N, 3) and a mask of those in front of the eye."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    clip = np.c_[p, np.ones(len(p))] @ camera.view_proj.T
    w = clip[:, 3]
    front = w > 1e-12
    safe_w = np.where(front, w, 1.0)
    ndc = clip[:, :2] / safe_w[:, None]
    px = np.c_[(ndc[:, 0] + 1.0) * 0.5 * camera.width, (ndc[:, 1] + 1.0) * 0.5 * camera.height]
    return px, front


def box_corners(bmin: np.ndarray, bmax: np.ndarray) -> np.ndarray:
    """The 8 corners (8, 3) of an axis-aligned box."""
    lo, hi = np.asarray(bmin, np.float64), np.asarray(bmax, np.float64)
    idx = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)])
    return np.where(idx == 1, hi, lo)
