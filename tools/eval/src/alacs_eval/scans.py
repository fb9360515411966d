"""Reading scan directories (docs/scan-format.md): manifest, frames, calibration, truth."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
from PIL import Image

from alacs_eval.camera import Calibration


@dataclasses.dataclass
class Frame:
    index: int
    file: str
    slide_mm: float
    exposure_us: int
    laser_on: bool
    crop: tuple[int, int, int, int] | None
    truth: str
    tag: str


@dataclasses.dataclass
class Scan:
    dir: Path
    kind: str
    width: int
    height: int
    target_id: int
    rough_mm: np.ndarray | None
    stops_mm: list[float]
    roi: tuple[int, int, int, int] | None
    frames: list[Frame]
    calibration_file: str
    truth_file: str
    note: str

    @staticmethod
    def load(path: Path | str) -> "Scan":
        path = Path(path)
        m = json.loads((path / "manifest.json").read_text())
        if m.get("format") != "alacs-scan/1":
            raise ValueError(f"{path}: not an alacs-scan/1 directory")
        s = m["scan"]
        frames = [Frame(int(f.get("index", i)), f["file"], float(f["slide_mm"]), int(f["exposure_us"]),
                        bool(f["laser_on"]), tuple(f["crop_px"]) if "crop_px" in f else None,
                        f.get("truth", ""), f.get("tag", "")) for i, f in enumerate(m["frames"])]
        return Scan(path, s.get("kind", ""), int(s["width_px"]), int(s["height_px"]), int(s.get("target_id", 0)),
                    np.asarray(s["rough_mm"], float) if "rough_mm" in s else None, list(s.get("stops_mm", [])),
                    tuple(s["roi_px"]) if "roi_px" in s else None, frames, s.get("calibration", "calibration.json"),
                    s.get("truth", ""), s.get("note", ""))

    def calibration(self) -> Calibration:
        return Calibration.load(self.dir / self.calibration_file)

    def region(self, frame: Frame, roi: tuple[int, int, int, int]) -> np.ndarray:
        """RGB uint8 pixels of `roi` (x, y, w, h) of a frame; unrecorded pixels are zero."""
        x, y, w, h = roi
        img = np.asarray(Image.open(self.dir / frame.file).convert("RGB"))
        out = np.zeros((h, w, 3), np.uint8)
        ox, oy = (frame.crop[0], frame.crop[1]) if frame.crop else (0, 0)
        # Intersection of the ROI with the stored part, in both coordinate systems.
        x0, y0 = max(x, ox), max(y, oy)
        x1, y1 = min(x + w, ox + img.shape[1]), min(y + h, oy + img.shape[0])
        if x1 > x0 and y1 > y0:
            out[y0 - y: y1 - y, x0 - x: x1 - x] = img[y0 - oy: y1 - oy, x0 - ox: x1 - ox]
        return out

    def truth_scene(self) -> dict:
        return json.loads((self.dir / self.truth_file).read_text())

    def truth_rows(self, frame: Frame, apple_id: int) -> np.ndarray:
        """Truth rows of one apple in a frame: structured array (row, column, x, y, z, flags)."""
        rows = []
        with open(self.dir / frame.truth, newline="") as f:
            for r in csv.DictReader(f):
                if int(r["apple_id"]) == apple_id:
                    rows.append((int(r["row"]), float(r["column_px"]), float(r["x_mm"]), float(r["y_mm"]),
                                 float(r["z_mm"]), int(r["flags"])))
        return np.array(rows, dtype=[("row", int), ("column", float), ("x", float), ("y", float), ("z", float),
                                     ("flags", int)])


def target_truth(scan: Scan) -> tuple[np.ndarray, float, np.ndarray]:
    """(centre, radius, approach point) of the scan's target apple."""
    for a in scan.truth_scene()["apples"]:
        if int(a["id"]) == scan.target_id:
            c = np.asarray(a["center_mm"], float)
            r = float(a["radius_mm"])
            approach = np.asarray(a["approach_mm"], float) if "approach_mm" in a else c - r * c / np.linalg.norm(c)
            return c, r, approach
    raise KeyError(f"{scan.dir}: no apple {scan.target_id} in the truth")
