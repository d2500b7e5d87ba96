"""The placement stage's entry point: where should each camera drone perch?

`optimise(mesh, regions, target, num_cameras, config, ...)` runs one of the searches and returns
the added cameras with the fitness, coverage and mean uncertainty after each, and the greedy
online bound (how close to the best possible arrangement on the candidate set the answer is).
Never imports rclpy.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from perch_common.errors import PerchError
from perch_common.mesh import Mesh, validate_mesh
from perch_common.raycast import RayScene, ray_scene
from perch_common.target import TargetVolume
from perch_common.transforms import parse_up_axis
from perch_common.types import CameraPlacement, ExclusionZone, PerchRegion
from perch_common.work import report, span
from perch_placement.cache import PlacementCache, mesh_digest
from perch_placement.config import PlacementConfig
from perch_placement.fitness import Evaluator, placement_cameras
from perch_placement.perches import Perch, Perches, seat_on_scan
from perch_placement.robustness import Arrangement, Assessment, LandingSampler, assess
from perch_placement.search import METHODS, SearchContext
from perch_placement.shortfall import shortfall_sentence

__all__ = ["PlacementConfig", "PlacementCache", "PlacementResult", "ReferenceResult", "optimise", "reference",
           "objective_value", "scene_for", "METHODS"]


@dataclass
class PlacementResult:
    """The added cameras and the score of the whole arrangement, with the work it took."""

    placements: list[CameraPlacement]   # the added cameras, in placement order
    fitness: float                      # of all cameras (fixed + added)
    coverage: float
    mean_uncertainty: float             # m^2, NaN when no point is seen
    upper_bound: float                  # greedy online bound (NaN when not computed)
    evaluations: int                    # camera arrangements simulated
    seconds: float
    message: str
    ray_tests: int = 0
    candidate_evaluations: int = 0      # candidate gains scored from the cached candidate set
    target_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cpu_seconds: float = 0.0            # CPU time of this process (all threads) during the call
    assessment: Assessment | None = None  # landing error, k-view coverage, loss of each camera (all cameras)
    coverage_bound: float = float("nan")  # LP upper bound on the best coverage on the candidate set
    certificate_status: str = ""           # how the bound was obtained, or why it is missing
    certificate_seconds: float = 0.0       # CPU seconds the certificate took (its budget's clock)


def scene_for(mesh: Mesh) -> RayScene:
    """The ray-cast scene of a mesh, validated first (raises MeshError for an unusable mesh); built
    once per mesh (perch_common.raycast.ray_scene)."""
    return ray_scene(validate_mesh(mesh, "environment mesh"))


def optimise(mesh: Mesh, regions: list[PerchRegion], target: TargetVolume, num_cameras: int,
             config: PlacementConfig | None = None, fixed: tuple[CameraPlacement, ...] | list = (),
             exclusions: tuple[ExclusionZone, ...] | list = (), method: str = "pso", seed: int = 0,
             cache: PlacementCache | None = None) -> PlacementResult:
    """Add `num_cameras` cameras to the `fixed` ones. Raises ValueError/PerchError on unusable input;
    returns fewer cameras (with the reason in .message) when no further perch adds fitness. A `cache`
    kept by the caller makes repeated requests on the same scene reuse its ray-cast scene and candidates."""
    start, cpu_start = time.perf_counter(), time.process_time()
    cfg = (config or PlacementConfig()).resolved()
    if method not in METHODS:
        raise ValueError(f"method '{method}': use one of {', '.join(METHODS)}")
    if num_cameras < 0:
        raise ValueError(f"num_cameras must be >= 0, got {num_cameras}")
    if target is None:
        raise ValueError("no target volume given")
    points = target.sample(cfg.target_points, seed=cfg.seed)
    if len(points) == 0:
        raise PerchError("the target volume yields no sample points (is it degenerate?)")
    report(0.0, "candidates")   # progress (perch_common.work); the searches report each camera
    ctx = search_context(mesh, regions, target, points, cfg, fixed, exclusions, seed, cache or PlacementCache())
    scene, evaluator, perches = ctx.evaluator.scene, ctx.evaluator, ctx.perches
    fixed_state = evaluator.info, evaluator.seen  # replaced, never modified in place, by the searches
    if num_cameras == 0:
        outcome_perches, reason = [], ""
    else:
        with span(0.1, 0.85):
            outcome = METHODS[method](ctx, num_cameras)
        outcome_perches, reason = outcome.perches, outcome.stop_reason
    if cfg.seat_depth > 0:
        outcome_perches = [seat_on_scan(p, scene, cfg.drone.radius, cfg.seat_depth) for p in outcome_perches]
    placements = _placements(evaluator, perches, outcome_perches, fixed_state, len(fixed))
    score = evaluator.current()
    bound = float("nan")
    if cfg.compute_bound and outcome_perches:
        bound = ctx.online_bound(len(outcome_perches))
    report(0.85, "robustness")
    assessment = assess_arrangement(evaluator, list(fixed) + placements, cfg)
    for placement, i in zip(placements, range(len(fixed), len(fixed) + len(placements))):
        annotate(placement, assessment, i)
    certificate = None
    if cfg.certificate and num_cameras > 0:
        from perch_placement.certificate import coverage_certificate

        certificate = coverage_certificate(ctx.candidates(), fixed_state[1], num_cameras, cfg.drone.min_spacing,
                                           cfg.certificate_seconds, evaluator.seen)
    seconds = time.perf_counter() - start
    text = _message(method, num_cameras, placements, score, bound,
                    shortfall_sentence(regions, num_cameras, len(placements), cfg.drone.min_spacing,
                                       reason, _capacity(perches, cfg, len(placements), num_cameras)) or reason)
    text += robustness_sentence(assessment, cfg, certificate, float(score.coverage))
    return PlacementResult(placements, float(score.fitness), float(score.coverage),
                           float(score.mean_uncertainty), bound, evaluator.evaluations, seconds, text,
                           evaluator.ray_tests, evaluator.candidate_evaluations, points,
                           time.process_time() - cpu_start, assessment,
                           certificate.coverage_bound if certificate else float("nan"),
                           certificate.status if certificate else "not computed",
                           certificate.seconds if certificate else 0.0)


def search_context(mesh: Mesh, regions: list[PerchRegion], target: TargetVolume, points: np.ndarray,
                   cfg: PlacementConfig, fixed=(), exclusions=(), seed: int = 0, cache: PlacementCache | None = None,
                   encoding: str | None = None) -> SearchContext:
    """The search context `optimise` works in (the references use the same one, so they search the same
    perches: the same border margin, exclusions and fixed drones): the evaluator holding the fixed cameras."""
    cache = cache or PlacementCache()
    digest = mesh_digest(mesh)
    scene = cache.scene(mesh, digest)  # validates the mesh when it is new
    evaluator = Evaluator(scene, points, cfg.camera, cfg.occlusion_epsilon)
    perches = Perches(regions, target.centroid(), cfg.drone, parse_up_axis(cfg.up_axis), encoding or cfg.encoding,
                      cfg.camera.max_zoom, cfg.border_margin)
    if fixed:
        evaluator.commit(*placement_cameras(fixed))
    return SearchContext(perches, evaluator, cfg, np.random.default_rng(seed), tuple(exclusions),
                         [np.asarray(p.drone_pose, np.float64)[:3, 3] for p in fixed], len(fixed), cache, digest,
                         Arrangement.of(fixed) if fixed else None)


@dataclass
class ReferenceResult:
    """A reference arrangement (greedy over a grid of candidates), seated and scored as an answer is."""

    fitness: list[float]        # nominal fitness after each camera (seated)
    objective: float            # the configured objective's value of the whole arrangement (objective_value)
    assessment: Assessment
    candidates: int
    arrangements_scored: int
    seconds: float
    perches: list = field(default_factory=list)


def reference(mesh: Mesh, regions: list[PerchRegion], target: TargetVolume, num_cameras: int,
              config: PlacementConfig | None = None, cache: PlacementCache | None = None,
              spacing: float | None = None, angles: int | None = None) -> ReferenceResult:
    """The exhaustive greedy reference for the configured objective on the problem `optimise` solves:
    the same target points, perches (border margin included) and seating on the scan. The nominal
    `fitness` objective runs greedy over the dense reference grid (reference_spacing, reference_angles)
    from the candidate set's cached visibility; the other objectives score every candidate of a grid
    (default the candidate set's: candidate_spacing, candidate_angles) with the objective itself."""
    from perch_placement.search.exhaustive import exhaustive_reference, objective_reference

    start = time.perf_counter()
    cfg = (config or PlacementConfig()).resolved()
    points = target.sample(cfg.target_points, seed=cfg.seed)
    ctx = search_context(mesh, regions, target, points, cfg, cache=cache, encoding="plane")
    if cfg.objective == "fitness":
        _, chosen, count, scored = exhaustive_reference(ctx, num_cameras, spacing, angles)
    else:
        chosen, count, scored = objective_reference(ctx, num_cameras, spacing or cfg.candidate_spacing,
                                                    angles or cfg.candidate_angles)
    if cfg.seat_depth > 0:
        chosen = [seat_on_scan(p, ctx.evaluator.scene, cfg.drone.radius, cfg.seat_depth) for p in chosen]
    placements = _placements(ctx.evaluator, ctx.perches, chosen, (np.zeros_like(ctx.evaluator.info),
                                                                np.zeros_like(ctx.evaluator.seen)), 0)
    assessment = assess_arrangement(ctx.evaluator, placements, cfg)
    return ReferenceResult([p.fitness for p in placements], objective_value(assessment, cfg), assessment, count,
                           scored, time.perf_counter() - start, chosen)


def objective_value(a: Assessment, cfg: PlacementConfig) -> float:
    """The configured objective of a whole arrangement, from its assessment: fitness, expected fitness
    under the landing error (the assessment's samples), fitness + kview_weight x k-view coverage, or
    fitness + resilience_weight x coverage after losing the worst camera."""
    if cfg.objective == "expected":
        return float(a.expected_fitness)
    if cfg.objective == "kview":
        return float(a.fitness + cfg.kview_weight * a.kview_coverage)
    if cfg.objective == "worst_case":
        worst = a.worst_coverage_without if len(a.coverage_without) > 1 else 0.0
        return float(a.fitness + cfg.resilience_weight * worst)
    return float(a.fitness)


def landing_sampler(cfg: PlacementConfig, samples: int | None = None) -> LandingSampler:
    """The configured landing-error model's seeded sampler (`samples` landings; default the assessment's)."""
    land = cfg.landing
    return LandingSampler(land.position_sigma, land.yaw_sigma_deg, samples or land.samples, land.seed,
                          land.gimbal_reaim, cfg.drone.pan_range_deg, cfg.drone.tilt_range_deg)


def assess_arrangement(evaluator: Evaluator, placements: list, cfg: PlacementConfig) -> Assessment:
    """The robustness of every camera in `placements` (fixed and added) under the configured model."""
    return assess(evaluator, Arrangement.of(placements), landing_sampler(cfg), cfg.kview_k, cfg.kview_angle_deg)


def annotate(placement: CameraPlacement, assessment: Assessment, i: int) -> None:
    """Copy camera i's robustness figures onto its placement."""
    placement.contribution = float(assessment.contribution[i])
    placement.expected_contribution = float(assessment.expected_contribution[i])
    placement.p5_contribution = float(assessment.p5_contribution[i])
    placement.coverage_without = float(assessment.coverage_without[i])
    placement.kview_coverage_without = float(assessment.kview_without[i])


def robustness_sentence(a: Assessment, cfg: PlacementConfig, certificate, coverage: float) -> str:
    """The reply's robustness part: landing error, k-view coverage, loss of one camera, certificate."""
    if a is None or not len(a.contribution):
        return ""
    land = cfg.landing
    text = (f"; under landing error ({100 * land.position_sigma:g} cm, {land.yaw_sigma_deg:g} deg, {a.samples} "
            f"samples) fitness {a.expected_fitness:.4f} expected, {a.p5_fitness:.4f} at the 5th percentile"
            f"; {cfg.kview_k}-view coverage (pair >= {cfg.kview_angle_deg:g} deg) {100 * a.kview_coverage:.1f} %")
    if a.short_of_views or a.short_of_angle:
        text += (f" ({a.short_of_views} target point(s) seen by fewer than {cfg.kview_k} cameras, "
                 f"{a.short_of_angle} seen only from views less than {cfg.kview_angle_deg:g} deg apart)")
    if len(a.contribution) > 1:
        text += (f"; losing one camera leaves coverage {100 * a.worst_coverage_without:.1f} % at worst "
                 f"({100 * a.mean_coverage_without:.1f} % mean), {cfg.kview_k}-view "
                 f"{100 * a.worst_kview_without:.1f} % at worst")
    if certificate is not None:
        if np.isfinite(certificate.coverage_bound) and coverage > certificate.coverage_bound + 1e-9:
            text += (f"; certificate: coverage {100 * coverage:.1f} % beats the LP bound on the candidate set "
                     f"({100 * certificate.coverage_bound:.1f} %): the search found perches off its grid")
        elif np.isfinite(certificate.coverage_bound):
            text += (f"; certificate: coverage is within {100 * max(certificate.gap(coverage), 0.0):.1f} % of the "
                     f"best possible on this candidate set (LP bound {100 * certificate.coverage_bound:.1f} %, "
                     "which bounds fitness too)")
        else:
            text += f"; certificate: {certificate.status}"
    return text


def _placements(evaluator: Evaluator, perches: Perches, chosen: list[Perch], fixed_state: tuple,
                fixed_count: int) -> list[CameraPlacement]:
    """Score the chosen cameras in order on top of the fixed ones (one batched view of all of them),
    recording the score after each, and leave the evaluator holding all of them."""
    evaluator.set_state(*fixed_state)
    if not chosen:
        return []
    before = float(evaluator.current().fitness)
    mask, info = evaluator.views(np.concatenate([p.camera_position for p in chosen]),
                                 np.concatenate([p.camera_rotation for p in chosen]),
                                 np.concatenate([p.zoom for p in chosen]))
    # Running sums from the fixed state, in placement order (as committing one by one would add them).
    infos = np.cumsum(np.concatenate([fixed_state[0][None], info]), axis=0)[1:]
    seens = np.logical_or.accumulate(np.concatenate([fixed_state[1][None], mask]), axis=0)[1:]
    scores = evaluator.score(infos, seens)
    evaluator.set_state(infos[-1], seens[-1])
    out = []
    for i, perch in enumerate(chosen):
        fitness = float(scores.fitness[i])
        out.append(CameraPlacement(
            drone_index=fixed_count + i, region_id=int(perches.regions[int(perch.region[0])].id),
            drone_pose=_matrix(perch.drone_rotation[0], perch.drone_position[0]),
            camera_pose=_matrix(perch.camera_rotation[0], perch.camera_position[0]),
            pan=float(perch.pan[0]), tilt=float(perch.tilt[0]), zoom=float(perch.zoom[0]),
            marginal_gain=fitness - before, fitness=fitness,
            coverage=float(scores.coverage[i]), mean_uncertainty=float(scores.mean_uncertainty[i])))
        before = fitness
    return out


def _capacity(perches: Perches, cfg: PlacementConfig, placed: int, asked: int) -> int | None:
    """How many drones the regions hold as placement sees them (border_margin inside their outlines);
    None when nothing is missing."""
    return len(perches.packing(cfg.drone.min_spacing)[0]) if placed < asked else None


def _matrix(rotation: np.ndarray, position: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation, position
    return m


def _message(method: str, asked: int, placements: list, score, bound: float, shortfall: str) -> str:
    """The reply's message: the shortfall sentence first when cameras are missing, then the scores."""
    text = f"{shortfall}. " if shortfall and len(placements) < asked else ""
    text += f"placed {len(placements)} of {asked} camera(s) with {method}"
    text += f"; fitness {float(score.fitness):.4f}, coverage {100 * float(score.coverage):.1f} %"
    if np.isfinite(bound) and bound > 0:
        text += (f"; greedy online bound {bound:.4f} on the candidate set: fitness is "
                 f"{100 * float(score.fitness) / bound:.1f} % of it (a strict bound only for submodular "
                 "objectives; covariance fusion is not, see perch_placement.optimality)")
    return text
