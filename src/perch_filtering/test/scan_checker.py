"""The real-scan tests' view of the project checker (perch_filtering.perch_check, which shares no
code with the filter): a perch's failures as a list of reasons (empty: safe)."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.target import TargetVolume
from perch_filtering.perch_check import CheckSpec, ScanChecker


class ScanOracle(ScanChecker):
    """The safety model on a real scan, perch by perch (see perch_check)."""

    def __init__(self, mesh: Mesh, target: TargetVolume, up: np.ndarray, spec: CheckSpec):
        super().__init__(mesh, up, spec, target)

    def failures(self, point: np.ndarray, normal: np.ndarray) -> list[str]:
        """The rules a perch at `point` with `normal` breaks (empty: safe)."""
        return self.verdict(point, normal).reasons
