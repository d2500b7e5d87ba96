"""Landing error statistics, k-view coverage, the loss of one camera and the coverage certificate,
checked analytically or by brute force on small cases."""

import importlib
import itertools
import math

import numpy as np
import pytest
from placement_rooms import box_room

from perch_common.target import TargetVolume
from perch_placement.camera import max_covariance_norm
from perch_placement.candidates import build_candidates
from perch_placement.certificate import cheap_bound, coverage_certificate, undominated
from perch_placement.config import PlacementConfig
from perch_placement.core import objective_value, optimise, reference, scene_for
from perch_placement.fitness import Evaluator
from perch_placement.perches import Perches
from perch_placement.robustness import Arrangement, KViewState, LandingSampler, assess, kview_mask

ROOM, REGIONS = box_room()
CAMERA = PlacementConfig().camera
# A drone on the wall y = 0 (normal +y), head down; its camera looks along +y, image-down = -z.
DRONE_ROT = np.column_stack([[0.0, 0, -1], [-1.0, 0, 0], [0.0, 1, 0]])
CAMERA_ROT = np.column_stack([[1.0, 0, 0], [0.0, 0, -1], [0.0, 1, 0]])


def wall_camera(x: float = 3.0, z: float = 1.5) -> Arrangement:
    """One camera 0.1 m off the wall y = 0 at (x, z), looking straight into the room."""
    return Arrangement(np.array([[x, 0.1, z]]), CAMERA_ROT[None], np.ones(1), DRONE_ROT[None])


def test_landing_offsets_and_yaw_have_the_configured_statistics():
    sampler = LandingSampler(0.1, 10.0, 20000, seed=3)
    nominal = wall_camera()
    landed = sampler.perturb(nominal)
    shift = landed.camera_position - nominal.camera_position
    # In the perch plane only, zero mean, sigma per in-plane axis.
    assert np.abs(shift[:, 1]).max() < 1e-12
    assert shift[:, [0, 2]].mean(axis=0) == pytest.approx([0, 0], abs=0.004)
    assert shift[:, [0, 2]].std(axis=0) == pytest.approx([0.1, 0.1], rel=0.03)
    # Yaw about the normal: the drone's forward axis turns in the wall's plane by N(0, 10 deg).
    forward = landed.drone_rotation[:, :, 0]
    assert np.abs(forward[:, 1]).max() < 1e-12
    yaw = np.degrees(np.arctan2(-forward[:, 0], -forward[:, 2]))
    assert yaw.std() == pytest.approx(10.0, rel=0.03)
    # Without re-aiming the optical axis turns with the body (here it is the normal: it stays).
    assert np.allclose(landed.camera_rotation[:, :, 2], [0, 1, 0])
    # Common random numbers: a second sampler with the same seed draws the same landings.
    again = LandingSampler(0.1, 10.0, 20000, seed=3).perturb(nominal)
    assert np.array_equal(again.camera_position, landed.camera_position)


def test_a_reaiming_gimbal_keeps_the_planned_axis_within_its_range():
    tilted = np.column_stack([[1.0, 0, 0], [0.0, math.cos(0.3), -math.sin(0.3)], [0.0, math.sin(0.3), math.cos(0.3)]])
    camera_rot = np.column_stack([CAMERA_ROT[:, 0], tilted @ np.array([0, 0, -1.0]), tilted @ np.array([0, 1.0, 0])])
    arrangement = Arrangement(np.array([[3.0, 0.1, 1.5]]), camera_rot[None], np.ones(1), DRONE_ROT[None])
    free = LandingSampler(0.0, 20.0, 500, seed=0, gimbal_reaim=True, pan_range_deg=180, tilt_range_deg=180)
    axis = free.perturb(arrangement).camera_rotation[:, :, 2]
    assert np.allclose(axis, camera_rot[:, 2], atol=1e-9)
    held = LandingSampler(0.0, 20.0, 500, seed=0).perturb(arrangement).camera_rotation[:, :, 2]
    assert np.degrees(np.arccos(np.clip(held @ camera_rot[:, 2], -1, 1))).max() > 5
    # A gimbal with no range cannot re-aim: the camera looks along the normal.
    stuck = LandingSampler(0.0, 20.0, 50, seed=0, gimbal_reaim=True, pan_range_deg=0, tilt_range_deg=0)
    assert np.allclose(stuck.perturb(arrangement).camera_rotation[:, :, 2], [0, 1, 0], atol=1e-9)


def test_expected_fitness_of_one_camera_matches_the_closed_form():
    # One point 2 m in front of the camera: one camera at distance d scores 1 - (d / R_max)^4, and an
    # in-plane landing offset r (r^2 = sigma^2 chi2_2) makes d^2 -> d^2 + r^2, so
    # E[s] = 1 - (d^4 + 4 sigma^2 d^2 + 8 sigma^4) / R_max^4 (yaw turns the view about the point).
    d, sigma = 2.0, 0.15
    ev = Evaluator(scene_for(ROOM), np.array([[3.0, 0.1 + d, 1.5]]), CAMERA)
    r_max = CAMERA.max_distance()
    a = assess(ev, wall_camera(), LandingSampler(sigma, 10.0, 20000, seed=1), 2, 30.0)
    assert a.fitness == pytest.approx(1 - (d / r_max) ** 4, abs=1e-9)
    expected = 1 - (d ** 4 + 4 * sigma ** 2 * d ** 2 + 8 * sigma ** 4) / r_max ** 4
    assert a.expected_fitness == pytest.approx(expected, abs=0.002)
    assert a.p5_fitness < a.expected_fitness < a.fitness
    # The score falls with r^2, so its 5th percentile is at r^2's 95th: sigma^2 * -2 ln 0.05.
    p5 = 1 - (d ** 2 - 2 * math.log(0.05) * sigma ** 2) ** 2 / r_max ** 4
    assert a.p5_fitness == pytest.approx(p5, abs=0.002)
    assert a.contribution[0] == pytest.approx(a.fitness) and a.coverage_without[0] == 0.0
    # No landing error: the statistics are the nominal values.
    exact = assess(ev, wall_camera(), LandingSampler(0.0, 0.0, 16, seed=1), 2, 30.0)
    assert exact.expected_fitness == pytest.approx(exact.fitness, abs=1e-12)
    assert exact.p5_fitness == pytest.approx(exact.fitness, abs=1e-12)
    assert max_covariance_norm(CAMERA) > 0


def test_kview_count_matches_a_hand_built_arrangement():
    points = np.array([[0.0, 0, 0], [5.0, 0, 0]])
    # Cameras 1 m from point 0 at 0, 20 and 90 degrees around it.
    cams = np.array([[1.0, 0, 0], [math.cos(math.radians(20)), math.sin(math.radians(20)), 0], [0.0, 1, 0]])
    seen = np.array([[1, 1], [1, 1], [1, 0]], bool)
    # Point 0: three views, pair (0, 2) 90 deg apart. Point 1 (5, 0, 0): views from cameras 0 and 1
    # differ by a few degrees only.
    assert kview_mask(cams, seen, points, 2, 30.0).tolist() == [True, False]
    assert kview_mask(cams, seen, points, 3, 30.0).tolist() == [True, False]
    assert kview_mask(cams, seen, points, 2, 3.0).tolist() == [True, True]
    # Without camera 2 the remaining views of point 0 are only 20 deg apart.
    assert kview_mask(cams[:2], seen[:2], points, 2, 30.0).tolist() == [False, False]
    assert kview_mask(cams[:2], seen[:2], points, 2, 20.0 - 1e-6).tolist() == [True, False]
    assert kview_mask(cams, seen, points, 1, 30.0).tolist() == [True, True]
    assert kview_mask(cams[:1], seen[:1], points, 2, 0.0).tolist() == [False, False]


def test_the_kview_objective_counts_as_the_measure_does():
    """KViewState (what the kview objective and its reference score) gives the k-view coverage of the
    whole arrangement that kview_mask measures, for every candidate added to hand-built cameras."""
    points = TargetVolume(center=np.array([3.0, 2.5, 1.2]), size=np.array([2.0, 2.0, 1.0])).sample(40, seed=1)
    ev = Evaluator(scene_for(ROOM), points, CAMERA)
    committed = Arrangement(np.array([[2.0, 0.1, 1.5], [4.0, 0.1, 2.0]]), np.stack([CAMERA_ROT] * 2), np.ones(2),
                            np.stack([DRONE_ROT] * 2))
    opposite_cam = np.column_stack([[-1.0, 0, 0], [0.0, 0, -1], [0.0, -1, 0]])
    opposite_drone = np.column_stack([[0.0, 0, -1], [1.0, 0, 0], [0.0, -1, 0]])
    candidates = Arrangement(np.array([[3.0, 0.2, 1.5], [3.0, 4.9, 1.5], [1.0, 4.9, 2.5]]),
                             np.stack([CAMERA_ROT, opposite_cam, opposite_cam]), np.ones(3),
                             np.stack([DRONE_ROT, opposite_drone, opposite_drone]))
    for k in (2, 3):
        state = KViewState(ev, committed, k, 30.0)
        got = state.coverage(candidates)
        for i in range(3):
            cams = np.concatenate([committed.camera_position, candidates.camera_position[i:i + 1]])
            rots = np.concatenate([committed.camera_rotation, candidates.camera_rotation[i:i + 1]])
            seen = ev.views(cams, rots, np.ones(3))[0]
            assert got[i] == pytest.approx(kview_mask(cams, seen, points, k, 30.0).mean(), abs=1e-12)
    # A camera facing the committed ones adds wide pairs; one beside them does not.
    state = KViewState(ev, committed, 2, 30.0)
    assert state.coverage(candidates)[1] > state.coverage(candidates)[0]


def test_loss_of_each_camera_in_a_hand_built_room():
    # Two cameras on opposite walls looking at each other's wall, the target between them:
    # each sees every point, so losing either keeps full coverage but loses the 2-view pairs.
    points = TargetVolume(center=np.array([3.0, 2.5, 1.5]), size=np.array([0.4, 0.4, 0.4])).sample(20, seed=0)
    ev = Evaluator(scene_for(ROOM), points, CAMERA)
    opposite_drone = np.column_stack([[0.0, 0, -1], [1.0, 0, 0], [0.0, -1, 0]])
    opposite_cam = np.column_stack([[-1.0, 0, 0], [0.0, 0, -1], [0.0, -1, 0]])
    arrangement = Arrangement(np.array([[3.0, 0.1, 1.5], [3.0, 4.9, 1.5]]),
                              np.stack([CAMERA_ROT, opposite_cam]), np.ones(2), np.stack([DRONE_ROT, opposite_drone]))
    a = assess(ev, arrangement, LandingSampler(0.05, 5.0, 32, seed=0), 2, 30.0)
    assert a.coverage == 1.0 and a.kview_coverage == 1.0
    assert a.coverage_without.tolist() == [1.0, 1.0]
    assert a.kview_without.tolist() == [0.0, 0.0]
    assert a.worst_kview_without == 0.0 and a.mean_coverage_without == 1.0
    # Each camera's contribution is the fitness lost without it (positive: fused views are better).
    alone = [assess(ev, Arrangement(*(f[i:i + 1] for f in (arrangement.camera_position, arrangement.camera_rotation,
                                                             arrangement.zoom, arrangement.drone_rotation))),
                    LandingSampler(0.0, 0.0, 1, seed=0), 2, 30.0).fitness for i in (1, 0)]
    assert a.contribution == pytest.approx(a.fitness - np.array(alone), abs=1e-12)
    assert (a.contribution > 0).all()


def _tiny_candidates():
    target = TargetVolume(center=np.array([3.0, 2.5, 1.0]), size=np.array([3.0, 2.5, 1.2]))
    ev = Evaluator(scene_for(ROOM), target.sample(30, seed=2), CAMERA)
    narrow = PlacementConfig().drone
    narrow.target_deviation_deg = 60.0
    perches = Perches(REGIONS, target.centroid(), narrow)
    cands = build_candidates(perches, ev, 1.0, 3)
    # A narrow field of view makes coverage a real choice (one camera no longer sees everything).
    cands.visible &= np.random.default_rng(0).random(cands.visible.shape) < 0.35
    return cands


def _brute_force_best(cands, base, k, spacing):
    """The best coverage of k candidates (drones `spacing` apart) added to `base`, by enumeration."""
    where = cands.drone_positions()
    visible = cands.visible.reshape(-1, cands.visible.shape[2])
    subsets = np.array(list(itertools.combinations(range(len(visible)), k)))
    pos = subsets // cands.orientations
    ok = np.ones(len(subsets), bool)
    for i, j in itertools.combinations(range(k), 2):
        gap = np.linalg.norm(where[pos[:, i]] - where[pos[:, j]], axis=1)
        ok &= gap >= spacing if spacing > 0 else True
    assert ok.sum() > 10
    return float((base | visible[subsets[ok]].any(axis=1)).mean(axis=1).max())


def _tiny_problem(positions):
    cands = _tiny_candidates()
    cands = cands.subset(np.arange(cands.positions) < positions)
    base = np.zeros(cands.visible.shape[2], bool)
    base[:3] = True   # points the fixed cameras already see
    return cands, base


@pytest.mark.parametrize("k, spacing, positions", [(1, 1.0, 99), (2, 1.0, 99), (2, 0.0, 99), (3, 1.6, 14)])
def test_coverage_certificate_is_never_below_the_brute_force_optimum(k, spacing, positions):
    cands, base = _tiny_problem(positions)
    visible = cands.visible.reshape(-1, cands.visible.shape[2])
    best = _brute_force_best(cands, base, k, spacing)
    cert = coverage_certificate(cands, base, k, spacing, time_limit=30.0)
    assert cert.status == "optimal"
    assert cert.coverage_bound >= best - 1e-9
    assert cert.coverage_bound <= 1.0
    assert cert.gap(best) >= -1e-9
    # The program-free bounds hold at any answer, and the certificate given one never goes below them.
    for answer in (base, base | visible[0], base | visible[:5].any(axis=0)):
        assert cheap_bound(cands, base, answer, k, spacing) >= best - 1e-9
        given = coverage_certificate(cands, base, k, spacing, time_limit=30.0, answer_seen=answer)
        assert given.coverage_bound >= best - 1e-9 and given.coverage_bound <= cert.coverage_bound + 1e-9


def test_certificate_is_reported_within_its_budget_when_the_steps_before_the_program_spend_it():
    """A loaded or slow machine: every reading of the budget's clock is 2 CPU seconds later, so the
    2-second budget is spent before the program. An answer still gets a bound (the program-free
    one, never below the optimum), and the certificate stops at its budget instead of solving."""
    cands, base = _tiny_problem(99)
    best = _brute_force_best(cands, base, 2, 1.0)
    answer = base | cands.visible[0, 0]
    ticks = itertools.count()
    cert = coverage_certificate(cands, base, 2, 1.0, time_limit=2.0, answer_seen=answer,
                                clock=lambda: 2.0 * next(ticks))
    assert cert.status.startswith("online coverage bound only: no time left for the linear program")
    assert best - 1e-9 <= cert.coverage_bound <= 1.0 and np.isfinite(cert.gap(float(answer.mean())))
    assert cert.seconds <= 2.0 + 2.0   # one step of the clock past the check, no program
    ticks = itertools.count()
    alone = coverage_certificate(cands, base, 2, 1.0, time_limit=2.0, clock=lambda: 2.0 * next(ticks))
    assert np.isnan(alone.coverage_bound) and alone.status.startswith("no bound: no time left")
    # With its budget on the process's CPU clock the program runs and gives the LP bound.
    solved = coverage_certificate(cands, base, 2, 1.0, time_limit=2.0, answer_seen=answer)
    assert solved.status == "optimal" and best - 1e-9 <= solved.coverage_bound <= cert.coverage_bound + 1e-9
    assert 0 <= solved.seconds <= 2.0


def test_dominated_orientations_are_dropped_and_equal_ones_kept_once():
    visible = np.array([[[1, 1, 0], [1, 0, 0], [1, 1, 0], [0, 0, 1]], [[0, 0, 0], [0, 1, 1], [0, 1, 0], [0, 0, 0]]], bool)
    assert undominated(visible).tolist() == [[True, False, False, True], [False, True, False, False]]


def test_every_answer_reports_robustness_and_a_certificate():
    target = TargetVolume(center=np.array([3.0, 2.5, 0.8]), size=np.array([2.0, 2.0, 1.2]))
    cfg = PlacementConfig(candidate_spacing=0.5)
    result = optimise(ROOM, REGIONS, target, 3, cfg, seed=0)
    a = result.assessment
    assert len(a.contribution) == 3 and a.samples == cfg.landing.samples
    assert a.fitness == pytest.approx(result.fitness, abs=1e-9)
    assert 0 <= a.p5_fitness <= a.expected_fitness <= 1
    for i, p in enumerate(result.placements):
        assert p.contribution == pytest.approx(a.contribution[i]) and np.isfinite(p.expected_contribution)
        assert p.coverage_without == pytest.approx(a.coverage_without[i])
    assert result.coverage <= result.coverage_bound + 1e-9 or "off its grid" in result.message
    assert "2-view coverage" in result.message and "losing one camera" in result.message
    # Every point short of 2-view coverage is counted once, with its reason.
    assert a.short_of_views + a.short_of_angle == round((1 - a.kview_coverage) * cfg.target_points)
    # A re-plan reports the whole set: the kept cameras are assessed with the new one.
    again = optimise(ROOM, REGIONS, target, 1, cfg, fixed=result.placements[:2], seed=0)
    assert len(again.assessment.contribution) == 3
    assert again.placements[0].drone_index == 2


def test_encoding_a_decoded_perch_gives_it_back():
    from perch_placement.search.greedy_pso import encode_perch

    perches = Perches(REGIONS, np.array([3.0, 2.5, 0.8]), PlacementConfig().drone)
    x = np.random.default_rng(4).random((20, perches.dims))
    decoded = perches.decode(x)
    for i in np.flatnonzero(decoded.inside):
        again = perches.decode(encode_perch(perches, decoded.take([i]))[None])
        assert again.region[0] == decoded.region[i]
        assert np.allclose(again.camera_position[0], decoded.camera_position[i], atol=1e-9)
        assert np.allclose(again.camera_rotation[0], decoded.camera_rotation[i], atol=1e-9)


@pytest.mark.parametrize("objective", ["expected", "kview", "worst_case"])
def test_other_objectives_refine_a_feasible_arrangement(objective):
    target = TargetVolume(center=np.array([3.0, 2.5, 0.8]), size=np.array([2.0, 2.0, 1.2]))
    cfg = PlacementConfig(candidate_spacing=0.5, objective=objective)
    result = optimise(ROOM, REGIONS, target, 3, cfg, seed=1)
    assert len(result.placements) == 3
    where = np.array([p.drone_pose[:3, 3] for p in result.placements])
    gaps = np.linalg.norm(where[:, None] - where[None], axis=-1)[np.triu_indices(3, 1)]
    assert gaps.min() >= cfg.drone.min_spacing - 1e-6
    nominal = optimise(ROOM, REGIONS, target, 3, PlacementConfig(candidate_spacing=0.5), seed=1)
    assert result.fitness > 0.5 * nominal.fitness
    assert objective_value(result.assessment, cfg) >= objective_value(nominal.assessment, cfg) - 1e-9
    moved = [p.drone_pose[:3, 3].tolist() for p in result.placements] != \
        [p.drone_pose[:3, 3].tolist() for p in nominal.placements]
    if objective == "worst_case":
        # Every camera alone sees the whole target here, so the loss term is a constant and the
        # nominal answer (refined too, same draws) is already the best.
        assert nominal.assessment.worst_coverage_without == 1.0 and not moved
    else:
        assert moved


def test_refining_the_nominal_answer_raises_fitness_and_keeps_its_2view_coverage(monkeypatch):
    """Coordinate ascent on greedy's nominal answer: never lower fitness or 2-view coverage, per seed
    (on seed 3 the unconstrained ascent lowers 2-view coverage 0.73 -> 0.64)."""
    greedy_pso = importlib.import_module("perch_placement.search.greedy_pso")
    target = TargetVolume(center=np.array([3.0, 2.5, 0.8]), size=np.array([3.0, 3.0, 1.2]))
    cfg = PlacementConfig(candidate_spacing=0.5, certificate=False)
    refined = [optimise(ROOM, REGIONS, target, 3, cfg, seed=s) for s in range(4)]
    monkeypatch.setattr(greedy_pso, "refine", lambda ctx, outcome, base: outcome)
    greedy = [optimise(ROOM, REGIONS, target, 3, cfg, seed=s) for s in range(4)]
    for r, g in zip(refined, greedy):
        assert r.fitness >= g.fitness - 1e-9
        assert r.assessment.kview_coverage >= g.assessment.kview_coverage - 1e-9
    assert max(r.fitness - g.fitness for r, g in zip(refined, greedy)) > 0.01


@pytest.mark.parametrize("objective", ["fitness", "expected", "kview", "worst_case"])
def test_greedy_pso_reaches_the_exhaustive_reference_under_each_objective(objective):
    """The reference solves the answer's problem (same perches, border margin, seating) under the same
    objective; greedy PSO's mean objective over seeds reaches 99 % of it."""
    target = TargetVolume(center=np.array([3.0, 2.5, 0.8]), size=np.array([2.0, 2.0, 1.2]))
    cfg = PlacementConfig(candidate_spacing=0.5, objective=objective, certificate=False, border_margin=0.4)
    cfg.landing.samples, cfg.landing.search_samples = 16, 4
    ref = reference(ROOM, REGIONS, target, 2, cfg, spacing=0.4, angles=5)
    assert len(ref.perches) == 2 and ref.objective == pytest.approx(objective_value(ref.assessment, cfg))
    assert ref.fitness[-1] == pytest.approx(ref.assessment.fitness, abs=1e-9)
    for perch in ref.perches:  # the answer's border margin: 0.4 m inside the rectangle
        region = REGIONS[int(perch.region[0])]
        uv = region.frame.to_plane(perch.drone_position)[0]
        assert (np.abs(uv) <= np.abs(region.polygons[0][0]).max(axis=0) - 0.4 + 1e-6).all()
    runs = [optimise(ROOM, REGIONS, target, 2, cfg, seed=s) for s in range(3)]
    assert np.mean([objective_value(r.assessment, cfg) for r in runs]) >= 0.99 * ref.objective
