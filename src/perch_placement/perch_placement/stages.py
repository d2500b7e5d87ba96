"""Perch regions through the upstream stages (segmentation, then filtering), imported lazily."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.target import TargetVolume


def filtered_regions(mesh: Mesh, target: TargetVolume, up=(0.0, 0.0, 1.0), surfaces=None) -> list:
    """Segment the mesh (unless surfaces are given) and filter the surfaces into perch regions."""
    from perch_filtering.core import filter_surfaces
    from perch_segmentation.core import segment_mesh

    if surfaces is None:
        surfaces = segment_mesh(mesh).surfaces
    return filter_surfaces(mesh, surfaces, target, np.asarray(up, np.float64)).regions
