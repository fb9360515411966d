"""The paper's evaluation (LLE displacement table, bRCE sweep, localization error against
distance with and without occlusion, success rate within 20 mm), reproduced on scan
directories of the digital twin, with the paper's own method beside ours."""

__all__ = ["camera", "metrics", "paper_line", "paper_method", "report", "scans", "twin"]
