"""The sensor's working envelope: where a rough position can be localized.

Depth: 500..2000 mm (the triangulation's working range, docs/geometry.md). Lateral: the
laser plane reaches x only while the slide is inside its stroke [0, stroke_mm], and the
camera must see it; the envelope at a depth is the intersection of both, on the camera's
optical-axis row (y = 0; the plane's small roll moves the edges < 0.1 mm per 100 mm of y).
Pinhole model: lens distortion (a few pixels at the image edge) is ignored.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

Vec3 = tuple[float, float, float]

MIN_DEPTH_MM = 500.0
MAX_DEPTH_MM = 2000.0
DEFAULT_STROKE_MM = 200.0
TABLE_DEPTHS_MM = (500.0, 750.0, 1000.0, 1200.0, 1500.0, 2000.0)


def _unit(v: Vec3) -> Vec3:
    n = math.sqrt(sum(x * x for x in v))
    return (v[0] / n, v[1] / n, v[2] / n)


def _dot(a: Vec3, b: Vec3) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@dataclass(frozen=True)
class Geometry:
    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    plane_normal: Vec3
    plane_offset_mm: float
    slide_axis: Vec3
    slide_scale: float
    source: str

    @staticmethod
    def default() -> Geometry:
        """The simulator's sensor (edge/sim/scene.cpp defaultScene): the laser 100 mm right
        of the camera at home, yawed 9.5° so that it crosses the optical axis at 1.2 m at
        mid-stroke."""
        yaw = math.radians(9.5)
        n = _unit((math.cos(yaw), -0.02, math.sin(yaw)))
        return Geometry(2048, 1536, 2400.0, 2402.0, 1026.3, 765.8, n,
                        _dot(n, (100.0, -60.0, 15.0)), _unit((1.0, 0.012, 0.004)), 1.003,
                        "default geometry (the simulator's sensor)")

    @staticmethod
    def from_calibration(path: Path) -> Geometry:
        """Read an alacs-calibration/1 JSON file (docs/calibration.md). Raises ValueError."""
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            cam, las = doc["camera"], doc["laser"]
            return Geometry(int(cam["width_px"]), int(cam["height_px"]), float(cam["fx_px"]),
                            float(cam["fy_px"]), float(cam["cx_px"]), float(cam["cy_px"]),
                            _unit(tuple(float(x) for x in las["plane_normal"])),  # type: ignore[arg-type]
                            float(las["plane_offset_mm"]),
                            _unit(tuple(float(x) for x in las["slide_axis"])),  # type: ignore[arg-type]
                            float(las.get("slide_scale", 1.0)), str(path))
        except (OSError, KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: not a calibration file: {exc}") from None

    def slide_for_point(self, p: Vec3) -> float:
        """Slide position (mm from home) whose laser plane passes through p (as the daemon's
        LaserGeometry::slideForPoint)."""
        k = self.slide_scale * _dot(self.plane_normal, self.slide_axis)
        return (_dot(self.plane_normal, p) - self.plane_offset_mm) / k

    def laser_x(self, slide_mm: float, z_mm: float) -> float:
        """x (mm) where the plane at ``slide_mm`` crosses the row y = 0 at depth z."""
        n = self.plane_normal
        k = self.slide_scale * _dot(n, self.slide_axis)
        return (self.plane_offset_mm + k * slide_mm - n[2] * z_mm) / n[0]


@dataclass(frozen=True)
class EnvelopeRow:
    depth_mm: float
    laser_x_mm: tuple[float, float]
    """x reached by the laser over the stroke."""
    view_x_mm: tuple[float, float]
    view_y_mm: tuple[float, float]
    x_mm: tuple[float, float] | None
    """The envelope: laser ∩ view, None if empty."""


def envelope(geo: Geometry, stroke_mm: float = DEFAULT_STROKE_MM,
             depths_mm: tuple[float, ...] = TABLE_DEPTHS_MM) -> list[EnvelopeRow]:
    rows = []
    for z in depths_mm:
        a, b = geo.laser_x(0.0, z), geo.laser_x(stroke_mm, z)
        laser = (min(a, b), max(a, b))
        view = (-geo.cx_px / geo.fx_px * z, (geo.width_px - geo.cx_px) / geo.fx_px * z)
        view_y = (-geo.cy_px / geo.fy_px * z, (geo.height_px - geo.cy_px) / geo.fy_px * z)
        lo, hi = max(laser[0], view[0]), min(laser[1], view[1])
        rows.append(EnvelopeRow(z, laser, view, view_y, (lo, hi) if lo < hi else None))
    return rows


def format_table(geo: Geometry, stroke_mm: float, rows: list[EnvelopeRow]) -> str:
    """Markdown table (the same text docs/can-protocol.md shows for the default geometry)."""
    out = [f"Working envelope: {geo.source}, stroke 0..{stroke_mm:g} mm, depth "
           f"{MIN_DEPTH_MM:g}..{MAX_DEPTH_MM:g} mm (x right, y down, z forward; row y = 0)",
           "",
           "| z (mm) | x reached by the laser (mm) | x in view (mm) | **x envelope (mm)** "
           "| y in view (mm) |",
           "|---|---|---|---|---|"]
    for r in rows:
        env = "none" if r.x_mm is None else f"**{r.x_mm[0]:.0f} .. {r.x_mm[1]:.0f}**"
        out.append(f"| {r.depth_mm:.0f} | {r.laser_x_mm[0]:.0f} .. {r.laser_x_mm[1]:.0f} | "
                   f"{r.view_x_mm[0]:.0f} .. {r.view_x_mm[1]:.0f} | {env} | "
                   f"{r.view_y_mm[0]:.0f} .. {r.view_y_mm[1]:.0f} |")
    return "\n".join(out) + "\n"
