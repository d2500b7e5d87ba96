"""Filter 1: orient each surface towards the free space it was observed from, class it, find the floor.

Not from the environment centroid (wrong in L-shaped and multi-room spaces): a surface's mesh
winding decides where it is consistent, visibility decides elsewhere (which side lies in the open
space connected to the target, and which side sees the target).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from perch_common.conventions import surface_class
from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.types import PlaneFrame, Surface, SurfaceClass
from perch_filtering.config import FilterConfig
from perch_filtering.sampling import project
from perch_filtering.voxels import FlightGrid

WINDING_CONSISTENT = 0.8   # share of area whose winding must agree for winding to decide
VISIBILITY_DECISIVE = 0.2  # score margin between the two sides for visibility to decide
CONVENTION_UNDECIDED = 0.15  # area share of agreement within this of one half: the winding convention is unknown
SAMPLES_PER_SURFACE = 32


@dataclass
class Orientation:
    """How a surface's normal was oriented: the sign applied and which evidence decided."""

    sign: float      # +1 keeps the input normal, -1 flips it
    decided_by: str  # "winding", "visibility" or "winding-majority"


def winding_votes(mesh: Mesh, surfaces: list[Surface]) -> np.ndarray:
    """Per surface, area-weighted agreement in [-1, 1] of face winding normals with the input normal."""
    normals, areas = mesh.face_normals(), mesh.face_areas()
    votes = np.zeros(len(surfaces))
    for i, s in enumerate(surfaces):
        f = s.face_indices
        if len(f) == 0:
            continue
        a = areas[f]
        votes[i] = float((np.sign(normals[f] @ s.frame.normal) * a).sum() / max(a.sum(), 1e-12))
    return votes


def visibility_scores(mesh: Mesh, surfaces: list[Surface], grid: FlightGrid, scene: RayScene,
                      target_centre: np.ndarray, seed: int, los_offset: float = 0.02) -> np.ndarray:
    """Per surface, score(front side) - score(back side), each side scored in [0, 2] as the share of
    sample points whose offset lies in open space connected to the target, plus the share that see it
    (sight lines start `los_offset` off the surface, as the line-of-sight filter's do)."""
    if not surfaces:
        return np.zeros(0)
    rng = np.random.default_rng(seed)
    areas, centroids = mesh.face_areas(), mesh.face_centroids()
    points, normals, owner = [], [], []
    for i, s in enumerate(surfaces):
        f = s.face_indices
        if len(f) and areas[f].sum() > 0:
            pick = rng.choice(f, size=min(SAMPLES_PER_SURFACE, len(f)), p=areas[f] / areas[f].sum())
            p = centroids[pick]
            p = p - np.outer((p - s.frame.origin) @ s.frame.normal, s.frame.normal)  # onto the plane
        else:
            p = s.frame.origin[None]
        points.append(p)
        normals.append(np.repeat(s.frame.normal[None], len(p), axis=0))
        owner.append(np.full(len(p), i))
    p, n, owner = np.concatenate(points), np.concatenate(normals), np.concatenate(owner)
    offset = 3.0 * grid.voxel  # past the voxels the surface itself occupies
    score = np.zeros(len(surfaces))
    for side in (1.0, -1.0):
        open_side = grid.lookup(grid.open_space, p + side * offset * n)
        start = p + side * los_offset * n
        facing = np.einsum("ij,ij->i", target_centre - p, side * n) > 0
        sees = facing & ~scene.occluded(start, np.repeat(target_centre[None], len(p), axis=0))
        per_point = open_side.astype(float) + sees
        score += side * np.bincount(owner, per_point, len(surfaces)) / np.bincount(owner, None, len(surfaces))
    return score


def orient(votes: np.ndarray, visibility: np.ndarray, areas: np.ndarray | None = None) -> list[Orientation]:
    """Winding where consistent (after checking the mesh's global winding convention), else visibility.

    The convention is read from the surfaces where both are clear, weighed by `areas` (m^2; equal
    weights without): a mesh wound inside-out is consistent but wrong everywhere, and its walls,
    floor and ceiling say so. Small pieces (a desk's underside, a shelf's faces) often look out on
    cramped space from their true front, so a count of surfaces is near half either way (a Quest
    scene model: 50 of 106, flipping every surface in one frame and not in another). Where the
    weighed agreement lies within CONVENTION_UNDECIDED of one half, the winding is not trusted: each
    surface is oriented by its visibility where that is decisive."""
    votes, visibility = np.asarray(votes, np.float64), np.asarray(visibility, np.float64)
    weights = np.ones(len(votes)) if areas is None else np.asarray(areas, np.float64)
    consistent = np.abs(votes) >= WINDING_CONSISTENT
    decisive = np.abs(visibility) >= VISIBILITY_DECISIVE
    both = consistent & decisive
    convention, trusted = 1.0, True
    if both.any() and weights[both].sum() > 0:
        agree = float(weights[both & (np.sign(votes) == np.sign(visibility))].sum() / weights[both].sum())
        convention = 1.0 if agree >= 0.5 else -1.0
        trusted = abs(agree - 0.5) > CONVENTION_UNDECIDED
    out = []
    for vote, vis, cons, dec in zip(votes, visibility, consistent, decisive):
        if cons and (trusted or not dec):
            out.append(Orientation(convention * np.sign(vote), "winding"))
        elif dec:
            out.append(Orientation(float(np.sign(vis)), "visibility"))
        else:
            out.append(Orientation(convention * (np.sign(vote) or 1.0), "winding-majority"))
    return out


def oriented_copy(surface: Surface, sign: float, up: np.ndarray, class_angle_deg: float) -> Surface:
    """A copy with the normal flipped by `sign`, a frame whose v axis follows up (walls), the boundary
    re-expressed in that frame, and the class from the oriented normal. The input is not touched."""
    old = surface.frame
    frame = PlaneFrame.from_normal(old.origin.copy(), sign * old.normal, up)
    boundary = [[frame.to_plane(old.to_world(np.asarray(ring, np.float64))) for ring in poly]
                for poly in surface.boundary]
    return replace(surface, frame=frame, boundary=boundary, face_indices=surface.face_indices.copy(),
                   mean_color=np.array(surface.mean_color, np.float64),
                   surface_class=surface_class(frame.normal, up, class_angle_deg))


def class_enabled(cls: SurfaceClass, config: FilterConfig) -> bool:
    """Whether the configuration allows perching on this surface class."""
    return {SurfaceClass.WALL: config.allow_walls, SurfaceClass.CEILING: config.allow_ceiling,
            SurfaceClass.FLOOR: config.allow_floor,
            SurfaceClass.INTERMEDIATE: config.allow_intermediate}.get(cls, False)


def find_floor(surfaces: list[Surface], mesh: Mesh, up: np.ndarray, config: FilterConfig) -> tuple[float, list[int]]:
    """Floor height along up and the ids of its pieces: the lowest large upward-facing surfaces,
    with every upward piece within floor_merge_tolerance of that height merged in. Without any,
    the 2nd percentile of the mesh's heights."""
    floors = [s for s in surfaces if s.surface_class == SurfaceClass.FLOOR]
    heights = np.array([s.frame.origin @ up for s in floors])
    large = np.array([s.area >= config.min_floor_area for s in floors], bool)
    if not large.any():
        return float(np.percentile(project(mesh.vertices, up)[:, 0], 2.0)), []
    lowest = heights[large].min()
    members = [i for i, h in enumerate(heights) if h <= lowest + config.floor_merge_tolerance]
    weights = np.array([floors[i].area for i in members])
    return float(np.average(heights[members], weights=weights)), [int(floors[i].id) for i in members]
