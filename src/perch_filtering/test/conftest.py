"""Make the test helpers (filtering_scenes, filtering_checker, filtering_accuracy) importable."""

import sys
from pathlib import Path

HERE = str(Path(__file__).resolve().parent)
if HERE not in sys.path:
    sys.path.insert(0, HERE)
