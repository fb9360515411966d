import sys
from pathlib import Path

# Importable without installing the package (tools/bootstrap.sh may not have).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
