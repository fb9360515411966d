"""Camera model and triangulation in numpy, the same as edge/geometry (OpenCV's
Brown-Conrady model, the laser plane n·X = d0 + scale·s·(n·a))."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np


@dataclasses.dataclass(frozen=True)
class Calibration:
    width_px: int
    height_px: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float]  # k1 k2 p1 p2 k3
    normal: np.ndarray
    offset_mm: float
    slide_axis: np.ndarray
    slide_scale: float

    @staticmethod
    def load(path: Path) -> "Calibration":
        d = json.loads(Path(path).read_text())
        c, l = d["camera"], d["laser"]
        return Calibration(int(c["width_px"]), int(c["height_px"]), float(c["fx_px"]), float(c["fy_px"]),
                           float(c["cx_px"]), float(c["cy_px"]), tuple(float(v) for v in c["distortion"]),
                           np.asarray(l["plane_normal"], float), float(l["plane_offset_mm"]),
                           np.asarray(l["slide_axis"], float), float(l["slide_scale"]))

    def plane_offset(self, slide_mm: float) -> float:
        return self.offset_mm + self.slide_scale * slide_mm * float(self.normal @ self.slide_axis)

    def slide_for_point(self, p: np.ndarray) -> float:
        return (float(self.normal @ p) - self.offset_mm) / (self.slide_scale * float(self.normal @ self.slide_axis))

    def _distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k1, k2, p1, p2, k3 = self.dist
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def project(self, pts: np.ndarray) -> np.ndarray:
        """N×3 camera-frame mm -> N×2 pixels (column, row)."""
        pts = np.atleast_2d(pts)
        xd, yd = self._distort(pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2])
        return np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], axis=1)

    def undistort(self, px: np.ndarray) -> np.ndarray:
        """N×2 pixels -> N×2 normalised (x/z, y/z), by fixed-point iteration to 1e-12."""
        px = np.atleast_2d(np.asarray(px, float))
        xd = (px[:, 0] - self.cx) / self.fx
        yd = (px[:, 1] - self.cy) / self.fy
        x, y = xd.copy(), yd.copy()
        for _ in range(100):
            fx, fy = self._distort(x, y)
            ex, ey = fx - xd, fy - yd
            x, y = x - ex, y - ey
            if max(np.max(np.abs(ex), initial=0), np.max(np.abs(ey), initial=0)) < 1e-13:
                break
        return np.stack([x, y], axis=1)

    def triangulate(self, px: np.ndarray, slide_mm: float) -> np.ndarray:
        """Pixels on the laser line at `slide_mm` -> N×3 points on the plane (mm)."""
        xn = self.undistort(px)
        rays = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)
        t = self.plane_offset(slide_mm) / (rays @ self.normal)
        return rays * t[:, None]
