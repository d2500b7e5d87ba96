"""Two storeys: each storey's perches are judged against its own floor, and a target of one volume a
storey keeps perches on both (a perch sees the volume of its own storey only)."""

from __future__ import annotations

import numpy as np
from filtering_scenes import Builder

from perch_common.target import TargetVolume
from perch_filtering.core import FilterConfig, filter_surfaces

UP = np.array([0.0, 0.0, 1.0])
WIDTH, DEPTH, HEIGHT, SLAB = 6.0, 5.0, 2.8, 0.25
STOREY = HEIGHT + SLAB   # the 2nd storey's floor height


def _storey(b: Builder, name: str, z0: float) -> None:
    """Floor, ceiling and inward walls of a closed WIDTH x DEPTH room from z0 to z0 + HEIGHT."""
    z1 = z0 + HEIGHT
    x, y = WIDTH, DEPTH
    b.quad(f"{name}.floor", [[0, 0, z0], [x, 0, z0], [x, y, z0], [0, y, z0]], [0, 0, 1])
    b.quad(f"{name}.ceiling", [[0, 0, z1], [x, 0, z1], [x, y, z1], [0, y, z1]], [0, 0, -1])
    b.quad(f"{name}.wall_south", [[0, 0, z0], [x, 0, z0], [x, 0, z1], [0, 0, z1]], [0, 1, 0])
    b.quad(f"{name}.wall_north", [[0, y, z0], [x, y, z0], [x, y, z1], [0, y, z1]], [0, -1, 0])
    b.quad(f"{name}.wall_west", [[0, 0, z0], [0, y, z0], [0, y, z1], [0, 0, z1]], [1, 0, 0])
    b.quad(f"{name}.wall_east", [[x, 0, z0], [x, y, z0], [x, y, z1], [x, 0, z1]], [-1, 0, 0])


def _two_storeys():
    b = Builder()
    _storey(b, "ground", 0.0)
    _storey(b, "upper", STOREY)
    # The slab's underside is the ground storey's ceiling; its top is the upper storey's floor.
    volumes = [TargetVolume(center=[3.0, 2.5, z + 1.0], size=[2.0, 1.5, 1.2]) for z in (0.0, STOREY)]
    surfaces = b.surfaces()
    names = {s.id: name for s, name in zip(surfaces, b.names())}
    return b.mesh(), surfaces, TargetVolume.union(volumes), names


def _lowest_kept(result, names, wall: str) -> float:
    heights = [r.mesh.vertices[:, 2].min() for r in result.regions if names[r.source_surface] == wall]
    assert heights, f"no perch kept on {wall}"
    return float(min(heights))


def test_each_storey_is_judged_against_its_own_floor():
    mesh, surfaces, target, names = _two_storeys()
    config = FilterConfig()
    result = filter_surfaces(mesh, surfaces, target, UP, config)
    # A wall perch's whole window needs min_recovery_height of fall: its lowest kept cell is the
    # window's half height plus that above the floor under it, on either storey.
    lowest = 0.5 * config.window_height + config.min_recovery_height
    for wall in ("wall_south", "wall_north", "wall_west", "wall_east"):
        ground = _lowest_kept(result, names, f"ground.{wall}")
        upper = _lowest_kept(result, names, f"upper.{wall}") - STOREY
        assert abs(ground - lowest) < 0.05, (wall, ground)
        assert abs(upper - lowest) < 0.05, (wall, upper)
    kept = {name.split(".")[0]: 0.0 for name in names.values()}
    for r in result.regions:
        kept[names[r.source_surface].split(".")[0]] += r.area
    assert kept["upper"] > 0.8 * kept["ground"] > 10.0, kept


def test_a_target_of_one_volume_a_storey_is_seen_volume_by_volume():
    """Each perch sees one of the two volumes; asked of all points, 0.6 share removes every perch."""
    mesh, surfaces, target, names = _two_storeys()
    per_volume = filter_surfaces(mesh, surfaces, target, UP, FilterConfig(min_visible_share=0.6))
    of_all = filter_surfaces(mesh, surfaces, target, UP, FilterConfig(min_visible_share=0.6,
                                                                        visibility_per_volume=False))
    assert sum(r.area for r in per_volume.regions) > 20.0
    assert not of_all.regions
    assert "line of sight" in of_all.message
