"""The fast paths of the search give the same numbers as the plain computations they replace.

Candidate sets pose candidates on demand and run frustum tests only where a position reaches a
point; candidate gains are kept between greedy steps and recomputed only where a reached point
changed; committed perches keep their views; the seeds' spacing test keeps each drone's mask. Each
is compared here, bit for bit, with the dense computation (the code before these paths), and a
whole `optimise` with the dense computations patched in must give the same answer.
"""

from dataclasses import replace

import numpy as np
import pytest
from placement_rooms import box_mesh, box_room

import perch_placement.candidates as candidates_module
from perch_common.mesh import Mesh
from perch_common.target import TargetVolume
from perch_common.types import ExclusionZone, PerchRegion, PlaneFrame, SurfaceClass
from perch_placement.camera import on_sensor
from perch_placement.candidates import CandidateGreedy, CandidateSet, GainMemo, build_candidates
from perch_placement.config import PlacementConfig, PsoConfig
from perch_placement.core import optimise, scene_for
from perch_placement.fitness import Evaluator
from perch_placement.perches import Perches
from perch_placement.search import SearchContext


def partitioned_room() -> tuple[Mesh, list]:
    """An 8 x 5 x 3 m room split by a partition with a doorway: perches behind it see little or nothing."""
    room, regions = box_room((8.0, 5.0, 3.0))
    wall = box_mesh((3.9, 0.0, 0.0), (4.1, 3.2, 3.0))
    mesh = Mesh(np.vstack([room.vertices, wall.vertices]), np.vstack([room.faces, wall.faces + len(room.vertices)]))
    return mesh, regions


MESH, REGIONS = partitioned_room()
TARGET = TargetVolume(center=np.array([2.0, 2.5, 0.8]), size=np.array([1.6, 1.6, 1.2]))
CONFIG = PlacementConfig(pso=PsoConfig(particles=20, iterations=12), candidate_spacing=0.4, candidate_angles=5)


def evaluator(cfg=CONFIG) -> Evaluator:
    cfg = cfg.resolved()
    return Evaluator(scene_for(MESH), TARGET.sample(cfg.target_points, seed=cfg.seed), cfg.camera)


def dense_candidates(perches: Perches, ev: Evaluator, spacing: float, angles: int, exclusions=(),
                     fixed=np.zeros((0, 3)), chunk: int = 1_000_000) -> CandidateSet:
    """The candidate set as built before the fast path: every candidate posed, every position's
    frustum tested against every point."""
    region, points = perches.grid(spacing)
    steps = np.linspace(0.0, 1.0, max(angles, 1)) if angles > 1 else np.array([0.5])
    gimbal = np.stack(np.meshgrid(steps, steps, indexing="ij"), -1).reshape(-1, 2)
    a = len(gimbal)
    probe = perches.pose(region, points, np.full((len(region), 2), 0.5))
    keep = perches.feasible(probe, fixed, exclusions)
    region, points = region[keep], points[keep]
    mounts = tuple(m[keep] for m in perches.mounts(probe.region, probe.drone_position))
    perch = perches.pose(np.repeat(region, a), np.repeat(points, a, axis=0), np.tile(gimbal, (len(region), 1)),
                         mounts=tuple(np.repeat(m, a, axis=0) for m in mounts))
    reach, delta, distance, unit = ev.reach(perch.camera_position[::a])
    visible = np.zeros((len(region), a, ev.count), bool)
    rotations = perch.camera_rotation.reshape(-1, a, 3, 3).transpose(0, 2, 1, 3).reshape(-1, 3, a * 3)
    per_chunk = max(1, chunk // (a * ev.count))
    for start in range(0, len(region), per_chunk):
        sl = slice(start, start + per_chunk)
        local = np.matmul(delta[sl].astype(np.float32), rotations[sl].astype(np.float32))
        in_frame = on_sensor(ev.camera, local.reshape(local.shape[0], ev.count, a, 3))
        visible[sl] = (in_frame & reach[sl, :, None]).transpose(0, 2, 1)
    reach = visible.any(axis=1)
    info = np.zeros(distance.shape + (6,))
    info[reach] = ev.information(distance[reach], unit[reach])
    cands = CandidateSet(perches, region, points, mounts, gimbal, visible, info[reach], reach)
    cands.dense_perch, cands.dense_info = perch, info
    return cands


def assert_same_perch(a, b) -> None:
    for name in a.__dataclass_fields__:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


@pytest.mark.parametrize("constrained", [False, True])
def test_candidate_set_is_the_dense_one(constrained):
    ev = evaluator()
    perches = Perches(REGIONS, TARGET.centroid(), CONFIG.drone)
    extra = dict(exclusions=(ExclusionZone(np.array([1.0, 0.0, 1.5]), 0.6),), fixed=np.array([[0.0, 2.5, 1.5]])) \
        if constrained else {}
    fast = build_candidates(perches, ev, 0.4, 5, **extra)
    dense = dense_candidates(perches, ev, 0.4, 5, **extra)
    live = dense.reach.any(axis=1)
    assert 0 < live.sum() < len(live)   # the partition hides some positions completely
    for name in ("visible", "pair_info", "reach", "region", "points", "gimbal"):
        assert np.array_equal(getattr(fast, name), getattr(dense, name)), name
    assert np.array_equal(fast.info, dense.dense_info)
    assert np.array_equal(fast.info_rows(np.array([[3, 0], [5, 5]])), dense.dense_info[np.array([[3, 0], [5, 5]])])
    assert_same_perch(fast.perch, dense.dense_perch)
    index = np.array([0, 7, len(fast) - 1])
    assert_same_perch(fast.take(index), dense.dense_perch.take(index))
    # A subset keeps its positions' candidates.
    keep = np.arange(fast.positions) % 3 == 0
    index = (np.flatnonzero(keep)[:, None] * fast.orientations + np.arange(fast.orientations)).reshape(-1)
    assert_same_perch(fast.subset(keep).perch, dense.dense_perch.take(index))
    assert np.array_equal(fast.subset(keep).info, dense.dense_info[keep])


def test_kept_gains_are_the_fresh_gains_as_cameras_come_and_go():
    ev = evaluator()
    cands = build_candidates(Perches(REGIONS, TARGET.centroid(), CONFIG.drone), ev, 0.4, 5)
    memo = GainMemo(cands)
    greedy = CandidateGreedy(cands, ev.info, ev.seen, CONFIG.drone.min_spacing)
    states = [(ev.info.copy(), ev.seen.copy())]
    for _ in range(4):
        greedy.step()
        states.append((greedy.info.copy(), greedy.seen.copy()))
    states.append(states[1])   # back to an earlier state (a search restoring one)
    rng = np.random.default_rng(0)
    for info, seen in states:
        for positions in (None, np.sort(rng.choice(cands.positions, cands.positions // 2, replace=False))):
            fresh = CandidateGreedy(cands, info, seen, 0.0).gains(positions)
            assert np.array_equal(memo.gains(info, seen, positions), fresh)
    assert memo.fresh.sum() < cands.positions   # positions reaching no point are never scored


def test_decoded_positions_and_drone_axes_are_each_regions_own():
    """Decoding works on every region at once: the same points, inside flags and drone axes as region
    by region (PlaneFrame.to_world, the region's own containment test, np.cross)."""
    frame = PlaneFrame.from_normal(np.array([4.0, 5.0, 1.5]), np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    ring = np.array([[-2.0, -1.0], [2.0, -1.0], [2.0, 0.0], [0.0, 0.0], [0.0, 1.0], [-2.0, 1.0]])  # an L
    l_shaped = PerchRegion(9, 9, SurfaceClass.WALL, frame, [[ring]], Mesh(np.zeros((0, 3)), np.zeros((0, 3), int)), 6.0)
    perches = Perches(REGIONS + [l_shaped], TARGET.centroid(), CONFIG.drone, border_margin=0.05)
    x = np.random.default_rng(4).random((600, perches.dims))
    region = perches.region_of(x[:, 0])
    points, inside = perches.surface_points(region, x[:, 1], x[:, 2])
    assert 0 < inside.sum() < len(inside)
    for r in np.unique(region):
        sel = region == r
        uv = perches.lo[r] + np.stack([x[sel, 1], x[sel, 2]], -1) * (perches.hi[r] - perches.lo[r])
        assert np.array_equal(points[sel], perches.regions[r].frame.to_world(uv))
        assert np.array_equal(inside[sel], perches._contains(r, uv))
    rotation = perches.drone_rotations(region, points)
    assert np.array_equal(rotation[:, :, 1], np.cross(rotation[:, :, 2], rotation[:, :, 0]))


def _dense_paths(monkeypatch) -> None:
    """Patch in the computations the fast paths replace."""
    monkeypatch.setattr(candidates_module, "build_candidates", dense_candidates)

    def fresh_gains(ctx, positions=None):
        return CandidateGreedy(ctx.candidates(), ctx.evaluator.info, ctx.evaluator.seen, 0.0).gains(positions)

    def fresh_views(ctx, perch):
        return ctx.evaluator.views(perch.camera_position, perch.camera_rotation, perch.zoom)

    def spaced(ctx, drones):
        where, drones = ctx.candidates().drone_positions(), np.asarray(drones, np.float64).reshape(-1, 3)
        if not len(drones):
            return np.ones(len(where), bool)
        return np.linalg.norm(where[:, None] - drones[None], axis=-1).min(axis=1) >= ctx.config.drone.min_spacing

    monkeypatch.setattr(SearchContext, "candidate_gains", fresh_gains)
    monkeypatch.setattr(SearchContext, "perch_views", fresh_views)
    monkeypatch.setattr(SearchContext, "spaced_candidates", spaced)


def _answer(result) -> tuple:
    return ([(p.region_id, np.asarray(p.drone_pose).tobytes(), np.asarray(p.camera_pose).tobytes(), p.pan, p.tilt,
              p.fitness, p.coverage, p.contribution, p.expected_contribution, p.coverage_without)
             for p in result.placements],
            result.fitness, result.coverage, result.mean_uncertainty, result.upper_bound, result.coverage_bound,
            result.evaluations, result.message)


@pytest.mark.parametrize("method,count", [("pso", 4), ("celf", 3)])
def test_optimise_gives_the_dense_paths_answer(monkeypatch, method, count):
    fixed_run = optimise(MESH, REGIONS, TARGET, 1, CONFIG, method="pso", seed=3)
    cases = [dict(), dict(fixed=fixed_run.placements, exclusions=[ExclusionZone(np.array([8.0, 2.5, 1.5]), 0.8)])]
    fast = [optimise(MESH, REGIONS, TARGET, count, CONFIG, method=method, seed=5, **case) for case in cases]
    _dense_paths(monkeypatch)
    dense = [optimise(MESH, REGIONS, TARGET, count, CONFIG, method=method, seed=5, **case) for case in cases]
    for a, b in zip(fast, dense):
        assert len(a.placements) == count
        assert _answer(a) == _answer(b)


def test_packed_fallback_gives_the_dense_paths_answer(monkeypatch):
    """More cameras than greedy can place on a small region: the packing restores states many times."""
    mesh, regions = box_room((3.0, 3.0, 2.6))
    small = [replace(regions[0])]
    target = TargetVolume(center=np.array([1.5, 1.5, 0.8]), size=np.array([1.0, 1.0, 1.0]))
    fast = optimise(mesh, small, target, 5, CONFIG, seed=2)
    _dense_paths(monkeypatch)
    assert _answer(fast) == _answer(optimise(mesh, small, target, 5, CONFIG, seed=2))
