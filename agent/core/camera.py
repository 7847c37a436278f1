"""A camera as an inspection is specified with it: sensor, lens and pixels; the ground
sampling distance (GSD) of an image of a surface point (beyond the thesis).

A pinhole camera of focal length f whose pixels are s wide sees one pixel on its axis under
the angle s/f [rad/px] (the *pixel angle*; off the axis a pixel's angle is smaller, by
cos α tangentially and cos² α radially). A surface point at range r [m] whose normal makes
the incidence β with the line to the camera is imaged at

    GSD = r · (s/f) / cos β   [m/px]

the footprint of one on-axis pixel there, stretched by 1/cos β along the tilt. It bounds the
GSD anywhere in the image from above, so a capture whose GSD this says meets the target meets
it. Image width W [px] and the pixel angle give the field of view: 2·atan(W·s / 2f).

The thesis' vision (eq. 3.1) stays the planner's objective. Its terms relate to these
numbers: cos β is the incidence term; f(r) peaks at d_opt, and a GSD target g is met head-on
up to the range g / (s/f), so d_opt should not exceed it (scenario validation says so).
Every length [m], angle [rad].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Camera:
    """A camera: its pixel angle s/f [rad/px] (the larger of the two axes for pixels that
    are not square), image size (width, height) [px] and shortest interval between two
    images ``trigger_s`` [s] (0: every control step)."""

    pixel_angle: float
    image_px: tuple[int, int]
    trigger_s: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pixel_angle) and self.pixel_angle > 0.0):
            raise ValueError(f"pixel_angle must be a positive angle [rad/px], got "
                             f"{self.pixel_angle}")
        if not (len(self.image_px) == 2 and min(self.image_px) > 0):
            raise ValueError(f"image_px must be two positive pixel counts, got {self.image_px}")
        if not (math.isfinite(self.trigger_s) and self.trigger_s >= 0.0):
            raise ValueError(f"trigger_s must be a non-negative interval [s], got "
                             f"{self.trigger_s}")

    @classmethod
    def from_sensor(cls, sensor_mm: tuple[float, float], focal_mm: float,
                    image_px: tuple[int, int], trigger_s: float = 0.0) -> Camera:
        """From sensor width and height [mm], focal length [mm] and image size [px]."""
        pitch = max(sensor_mm[0] / image_px[0], sensor_mm[1] / image_px[1])  # [mm/px]
        return cls(pitch / focal_mm, (int(image_px[0]), int(image_px[1])), trigger_s)

    @classmethod
    def from_fov(cls, fov: tuple[float, float], image_px: tuple[int, int],
                 trigger_s: float = 0.0) -> Camera:
        """From the full horizontal and vertical field of view [rad] and image size [px]."""
        angle = max(2.0 * math.tan(fov[0] / 2.0) / image_px[0],
                    2.0 * math.tan(fov[1] / 2.0) / image_px[1])
        return cls(angle, (int(image_px[0]), int(image_px[1])), trigger_s)

    @property
    def fov(self) -> tuple[float, float]:
        """Full horizontal and vertical field of view [rad]."""
        w, h = self.image_px
        return (2.0 * math.atan(w * self.pixel_angle / 2.0),
                2.0 * math.atan(h * self.pixel_angle / 2.0))

    @property
    def focal_px(self) -> float:
        """The focal length in pixels, f/s [px] (what photogrammetry calibrations give)."""
        return 1.0 / self.pixel_angle

    def ready(self, now: float, last: float | None) -> bool:
        """Whether an image may be taken at ``now`` [s] after the last one at ``last``."""
        return last is None or now - last >= self.trigger_s - 1e-9

    def range_for(self, gsd: float) -> float:
        """The range [m] at which a surface seen head-on is imaged at ``gsd`` [m/px]."""
        return gsd / self.pixel_angle


def ground_sampling_distance(P: Array, q: Array, u: Array, pixel_angle: float) -> Array:
    """GSD r·(s/f)/cos β [m/px] of landmarks (q, u) (m, 3) from camera positions P (K, 3)
    [m; world ENU]: (K, m); +inf where the landmark faces away (cos β ≤ 0)."""
    D = q[None, :, :] - P[:, None, :]
    r = np.sqrt(np.einsum("kmi,kmi->km", D, D))
    cos_b = -np.einsum("kmi,mi->km", D, u) / np.where(r > 0.0, r, 1.0)
    out = np.full(r.shape, np.inf)
    ok = cos_b > 0.0
    out[ok] = r[ok] * pixel_angle / cos_b[ok]
    return out
