"""The ALACS paper's Laser Line Extraction, in numpy, as published (docs/lle.md).

    from paper_lle import paper_lle
    line = paper_lle(rgb)            # rgb: H x W x 3 uint8, RGB order
    line.rows, line.columns          # focused centre of every row with candidates
    line.column_at(rows)             # the fitted 4th-order curve

Importable without installing: ``sys.path.insert(0, "tools/paper_lle")``.
"""

from paper_lle.core import PaperLine, brce, focus_rows, paper_lle, remove_noise

__all__ = ["PaperLine", "brce", "focus_rows", "paper_lle", "remove_noise"]
