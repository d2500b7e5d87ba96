"""`perch bench placement`: fitness, time and evaluations per method and camera count, against the
exhaustive reference; prints JSON and writes a markdown table shaped like the original's Table 7."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from perch_common.bench import emit, peak_rss_mb
from perch_common.cli_types import non_negative_int, positive_float, positive_int
from perch_placement.cli_problem import add_problem_arguments, load_config, load_problem, up_of

LABELS = {"pso": "Greedy PSO", "random": "Random", "grid": "Grid", "naive": "Naive PSO", "celf": "CELF + refine",
          "pso-unseeded": "Greedy PSO (unseeded)"}


def register(sub) -> None:
    """Add `perch bench placement`: the searches against the exhaustive reference."""
    parser = sub.add_parser("placement", help="placement search: methods vs the exhaustive reference")
    add_problem_arguments(parser, mesh_positional=False)
    parser.add_argument("--cameras", type=positive_int, default=5, help="largest camera count N >= 1 (runs 1..N)")
    parser.add_argument("--seeds", type=positive_int, default=30, help="search seeds per method and count (>= 1)")
    parser.add_argument("--methods", default=parser_default_methods(),
                        help="comma-separated: pso, pso-unseeded, random, grid, naive, celf")
    parser.add_argument("--reference", action="store_true", help="also run the exhaustive reference")
    parser.add_argument("--density", type=positive_float, default=1000.0,
                        help="points/m^3 for coverage and uncertainty (> 0)")
    parser.add_argument("--bound-check", type=non_negative_int, default=0, metavar="N",
                        help="also check the greedy online bound by exhaustive search on N >= 0 small rooms")
    parser.add_argument("--objectives", default="",
                        help="comma-separated objectives to compare side by side at --cameras with greedy PSO "
                             "(fitness, expected, kview, worst_case): fitness, expected fitness under landing "
                             "error, k-view coverage, worst single-camera loss, certificate gap, seconds; "
                             "with it, --methods defaults to none")
    parser.add_argument("--reference-grid", type=grid_text, default="", metavar="SPACING,ANGLES",
                        help="grid of the kview and worst_case references (default: the candidate set's)")
    parser.add_argument("--expected-reference-grid", type=grid_text, default="0.3,5", metavar="SPACING,ANGLES",
                        help="grid of the expected objective's reference: it scores every candidate under "
                             "landing.search_samples landings, that many times the work (default 0.3,5)")
    parser.add_argument("--json", action="store_true", help="print JSON (always on; kept for scripts)")
    parser.add_argument("--table", help="write the markdown table here (default: stderr)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the placement benchmark; prints JSON and the Table-7 style markdown table."""
    from dataclasses import replace

    from perch_placement.core import PlacementCache, optimise
    from perch_placement.fitness import Evaluator

    config = load_config(args.params).resolved()
    problem = load_problem(args, up_of(config))
    started = time.perf_counter()
    cache = PlacementCache()  # one scene and candidate set for every run, as the node keeps them
    scene = cache.scene(problem.mesh)
    build_seconds = time.perf_counter() - started
    dense = Evaluator(scene, problem.target.sample(density=args.density, seed=config.seed + 1), config.camera,
                      config.occlusion_epsilon)
    result_rays = _ray_throughput(scene, problem)
    counts = list(range(1, args.cameras + 1))
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    objectives = [o.strip() for o in args.objectives.split(",") if o.strip()]
    if objectives and args.methods == parser_default_methods():
        methods = []
    result = {"benchmark": "placement", "problem": problem.name, "regions": len(problem.regions),
              "regions_route": problem.route, "region_area_m2": float(sum(r.area for r in problem.regions)),
              "target_volume_m3": problem.target.volume(), "target_points": config.target_points,
              "dense_points": dense.count, "seeds": args.seeds, "scene_build_seconds": build_seconds,
              "occlusion_tests_per_second": result_rays, "pso": vars(config.pso), "methods": {}}
    for method in methods:
        cfg = replace(config, pso=replace(config.pso, seeded=0)) if method == "pso-unseeded" else config
        name = "pso" if method == "pso-unseeded" else method
        per_count = {}
        for k in counts:
            runs = [optimise(problem.mesh, problem.regions, problem.target, k, cfg, method=name, seed=s,
                             cache=cache) for s in range(args.seeds)]
            per_count[str(k)] = _summary(runs, dense)
            print(f"{method} k={k}: fitness {per_count[str(k)]['fitness_mean']:.4f} "
                  f"median {per_count[str(k)]['seconds_median']:.3f} s", file=sys.stderr)
        result["methods"][method] = per_count
    if objectives:
        grids = {"expected": _grid(args.expected_reference_grid), "kview": _grid(args.reference_grid),
                 "worst_case": _grid(args.reference_grid)}
        result["objectives"] = compare_objectives(problem, config, cache, objectives, args.cameras, args.seeds,
                                                  args.reference, grids)
    if args.reference and (methods or not objectives):  # with objectives only, each row has its own
        result["reference"] = _reference(problem, config, cache, args.cameras, dense)
    if args.bound_check:
        from perch_placement.optimality import bound_check_suite

        result["bound_check"] = bound_check_suite(args.bound_check)
    result["checks"] = _checks(result, counts)
    result["peak_rss_mb"] = peak_rss_mb()
    result["load_average"] = list(os.getloadavg())
    table = markdown_table(result, counts) if methods or not objectives else ""
    if objectives:
        table += objectives_table(result)
    if args.table:
        Path(args.table).write_text(table)
    else:
        print(table, file=sys.stderr)
    return emit(result)


def grid_text(text: str) -> str:
    """argparse type of --reference-grid: 'SPACING,ANGLES' (spacing > 0 m, angles >= 1) or empty; the text as given."""
    if text.strip():
        parts = text.split(",")
        try:
            if len(parts) != 2:
                raise argparse.ArgumentTypeError("")
            positive_float(parts[0].strip())
            positive_int(parts[1].strip())
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(f"{text!r}: give SPACING,ANGLES (a spacing > 0 m and a number of "
                                             "angles >= 1, e.g. 0.3,5)") from None
    return text


def _grid(text: str) -> tuple[float | None, int | None]:
    """'SPACING,ANGLES' as numbers; (None, None) when empty (the reference's default grid)."""
    if not text.strip():
        return None, None
    spacing, angles = text.split(",")
    return float(spacing), int(angles)


def parser_default_methods() -> str:
    """The --methods default (an explicit --methods with --objectives still runs the methods)."""
    return "pso,random,grid,naive,celf"


def compare_objectives(problem, config, cache, objectives: list, k: int, seeds: int, with_reference: bool = False,
                       grids: dict | None = None) -> dict:
    """Greedy PSO with each objective at k cameras over `seeds` seeds; every arrangement is assessed
    with the same landing samples (the configured model and seed: common random numbers). With
    `with_reference`, each objective's exhaustive greedy reference (perch_placement.core.reference) and
    the ratio of the mean objective value to it."""
    from dataclasses import replace

    from perch_placement.core import objective_value, optimise, reference

    out = {}
    for objective in objectives:
        cfg = replace(config, objective=objective)
        runs = [optimise(problem.mesh, problem.regions, problem.target, k, cfg, method="pso", seed=s, cache=cache)
                for s in range(seeds)]
        a = [r.assessment for r in runs]
        gap = [1 - r.coverage / r.coverage_bound if np.isfinite(r.coverage_bound) and r.coverage_bound > 0
               else np.nan for r in runs]
        out[objective] = {
            "fitness_mean": float(np.mean([r.fitness for r in runs])),
            "fitness_std": float(np.std([r.fitness for r in runs])),
            "expected_fitness_mean": float(np.mean([x.expected_fitness for x in a])),
            "expected_fitness_std": float(np.std([x.expected_fitness for x in a])),
            "p5_fitness_mean": float(np.mean([x.p5_fitness for x in a])),
            "coverage_mean": float(np.mean([r.coverage for r in runs])),
            "kview_coverage_mean": float(np.mean([x.kview_coverage for x in a])),
            "worst_loss_coverage_mean": float(np.mean([r.coverage - x.worst_coverage_without for r, x in zip(runs, a)])),
            "worst_coverage_without_mean": float(np.mean([x.worst_coverage_without for x in a])),
            "worst_kview_without_mean": float(np.mean([x.worst_kview_without for x in a])),
            "certificate_gap_mean": float(np.nanmean(gap)) if np.isfinite(gap).any() else float("nan"),
            "certificate_gap_max": float(np.nanmax(gap)) if np.isfinite(gap).any() else float("nan"),
            "certificates": int(np.isfinite(gap).sum()),
            "seconds_median": float(np.median([r.seconds for r in runs])),
            "certificate_seconds_median": float(np.median([r.certificate_seconds for r in runs])),
            "certificate_seconds_max": float(np.max([r.certificate_seconds for r in runs])),
            "cameras_placed_mean": float(np.mean([len(r.placements) for r in runs])),
            "expected_fitness_per_seed": [x.expected_fitness for x in a],
            "objective_mean": float(np.mean([objective_value(x, cfg) for x in a]))}
        if with_reference:
            spacing, angles = (grids or {}).get(objective, (None, None))
            ref = reference(problem.mesh, problem.regions, problem.target, k, cfg, cache, spacing, angles)
            out[objective].update({
                "reference_objective": ref.objective, "reference_fitness": ref.fitness[-1] if ref.fitness else 0.0,
                "reference_candidates": ref.candidates, "reference_seconds": ref.seconds,
                "reference_grid": [spacing or (config.reference_spacing if objective == "fitness" else
                                               config.candidate_spacing),
                                   angles or (config.reference_angles if objective == "fitness" else
                                              config.candidate_angles)],
                "objective_ratio_to_reference": out[objective]["objective_mean"] / max(ref.objective, 1e-12)})
        print(f"objective {objective}: fitness {out[objective]['fitness_mean']:.4f} expected "
              f"{out[objective]['expected_fitness_mean']:.4f} median {out[objective]['seconds_median']:.3f} s",
              file=sys.stderr)
    base = out.get("fitness")
    if base:
        for objective, row in out.items():
            diff = np.array(row["expected_fitness_per_seed"]) - np.array(base["expected_fitness_per_seed"])
            row["expected_gain_vs_fitness_mean"] = float(diff.mean())
            row["expected_gain_vs_fitness_wins"] = int((diff > 0).sum())
            row["seconds_ratio_vs_fitness"] = row["seconds_median"] / max(base["seconds_median"], 1e-9)
    return {"cameras": k, "seeds": seeds, "landing": vars(config.landing), "kview_k": config.kview_k,
            "kview_angle_deg": config.kview_angle_deg, "rows": out}


def objectives_table(result: dict) -> str:
    """One row per objective: the robustness figures side by side (means over seeds)."""
    o = result["objectives"]
    land = o["landing"]
    lines = [f"Objectives on {result['problem']}, {o['cameras']} cameras, {o['seeds']} seeds (means; landing error "
             f"{100 * land['position_sigma']:g} cm / {land['yaw_sigma_deg']:g} deg, {land['samples']} common samples; "
             f"{o['kview_k']}-view at {o['kview_angle_deg']:g} deg)", "",
             "| Objective | Fitness | Expected under error | 5th pct | k-view cov. | Worst 1-camera loss (cov.) "
             "| k-view after worst loss | Certificate gap (cov.) | Seconds (median) | Objective / reference |",
             "|" + "---|" * 10]
    for name, r in o["rows"].items():
        ratio = (f"{r['objective_mean']:.4f} / {r['reference_objective']:.4f} = "
                 f"{100 * r['objective_ratio_to_reference']:.1f} %") if "reference_objective" in r else "-"
        lines.append(f"| {name} | {r['fitness_mean']:.4f} ± {r['fitness_std']:.4f} | {r['expected_fitness_mean']:.4f} "
                     f"| {r['p5_fitness_mean']:.4f} | {100 * r['kview_coverage_mean']:.1f} % "
                     f"| {100 * r['worst_loss_coverage_mean']:.1f} pt | {100 * r['worst_kview_without_mean']:.1f} % "
                     f"| {100 * r['certificate_gap_mean']:.1f} % ({r['certificates']}/{o['seeds']}) "
                     f"| {r['seconds_median']:.2f} | {ratio} |")
    return "\n".join(lines) + "\n"


def _ray_throughput(scene, problem, count: int = 1_000_000) -> float:
    """Occlusion tests per second on segments from camera positions on the regions to target points."""
    rng = np.random.default_rng(0)
    cameras = np.concatenate([r.mesh.vertices + 0.1 * r.frame.normal for r in problem.regions])
    starts = cameras[rng.integers(0, len(cameras), count)]
    ends = problem.target.sample(1000, seed=1)
    ends = ends[rng.integers(0, len(ends), count)]
    scene.occluded(starts[:1000], ends[:1000])  # warm-up
    started = time.perf_counter()
    scene.occluded(starts, ends)
    return count / (time.perf_counter() - started)


def _dense_score(dense, placements) -> tuple[float, float]:
    from perch_placement.fitness import placement_cameras

    dense.reset()
    if placements:
        dense.commit(*placement_cameras(placements))
    score = dense.current()
    return float(score.coverage), float(score.mean_uncertainty)


def _summary(runs, dense) -> dict:
    fitness = np.array([r.fitness for r in runs])
    seconds = np.array([r.seconds for r in runs])
    cover, unc = zip(*[_dense_score(dense, r.placements) for r in runs])
    return {"fitness_mean": float(fitness.mean()), "fitness_std": float(fitness.std()),
            "fitness_min": float(fitness.min()), "seconds_median": float(np.median(seconds)),
            "seconds_mean": float(seconds.mean()), "seconds_first": float(seconds[0]),
            "cpu_seconds_median": float(np.median([r.cpu_seconds for r in runs])),
            "evaluations_mean": float(np.mean([r.evaluations for r in runs])),
            "candidate_evaluations_mean": float(np.mean([r.candidate_evaluations for r in runs])),
            "ray_tests_mean": float(np.mean([r.ray_tests for r in runs])),
            "upper_bound_mean": float(np.nanmean([r.upper_bound for r in runs])),
            "coverage_dense_mean": float(np.mean(cover)), "uncertainty_dense_mean_m2": float(np.nanmean(unc)),
            "cameras_placed_mean": float(np.mean([len(r.placements) for r in runs]))}


def _reference(problem, config, cache, k: int, dense) -> dict:
    """The nominal exhaustive reference (perch_placement.core.reference: the same perches, border margin
    and seating on the scan as an answer), with dense coverage and uncertainty after each camera."""
    from perch_placement.core import reference

    ref = reference(problem.mesh, problem.regions, problem.target, k, config, cache)
    cover, unc = [], []
    dense.reset()
    for perch in ref.perches:
        dense.commit(perch.camera_position, perch.camera_rotation, perch.zoom)
        score = dense.current()
        cover.append(float(score.coverage))
        unc.append(float(score.mean_uncertainty))
    return {"fitness": ref.fitness, "coverage_dense": cover, "uncertainty_dense_m2": unc, "candidates": ref.candidates,
            "arrangements_scored": ref.arrangements_scored, "seconds": ref.seconds,
            "grid": {"spacing_m": config.reference_spacing, "angles": config.reference_angles}}


def _checks(result: dict, counts: list) -> dict:
    checks = {}
    pso = result["methods"].get("pso")
    last = str(counts[-1])
    if pso:
        checks["pso_median_seconds_below_1"] = pso[last]["seconds_median"] < 1.0
        for other in ("random", "grid"):
            if other in result["methods"]:
                checks[f"pso_above_{other}"] = all(pso[str(k)]["fitness_mean"] > result["methods"][other][str(k)]["fitness_mean"]
                                                  for k in counts)
    ref = result.get("reference")
    if ref:
        checks["reference_below_300s"] = ref["seconds"] < 300
        if pso:
            ratios = [pso[str(k)]["fitness_mean"] / ref["fitness"][k - 1] for k in counts if k <= len(ref["fitness"])]
            checks["pso_ratio_to_reference"] = ratios
            checks["pso_at_least_99pct_of_reference"] = bool(ratios) and min(ratios) >= 0.99
        cov, unc = ref["coverage_dense"], ref["uncertainty_dense_m2"]
        checks["reference_coverage_rises"] = all(b >= a for a, b in zip(cov, cov[1:]))
        checks["reference_uncertainty_falls"] = all(b <= a for a, b in zip(unc, unc[1:]))
    rows = result.get("objectives", {}).get("rows", {})
    ratios = {name: r["objective_ratio_to_reference"] for name, r in rows.items() if "objective_ratio_to_reference" in r}
    if ratios:
        checks["objective_ratio_to_reference"] = ratios
        checks["objectives_at_least_99pct_of_reference"] = min(ratios.values()) >= 0.99
    if pso:
        cov = [pso[str(k)]["coverage_dense_mean"] for k in counts]
        unc = [pso[str(k)]["uncertainty_dense_mean_m2"] for k in counts]
        checks["pso_coverage_rises"] = all(b >= a for a, b in zip(cov, cov[1:]))
        checks["pso_uncertainty_falls"] = all(b <= a for a, b in zip(unc, unc[1:]))
    return checks


def markdown_table(result: dict, counts: list) -> str:
    """Rows: camera counts. Columns: the reference and each method, fitness mean +- std (median s)."""
    methods = list(result["methods"])
    ref = result.get("reference")
    head = ["Cameras"] + (["Exhaustive reference"] if ref else []) + [LABELS.get(m, m) for m in methods]
    lines = [f"Placement on {result['problem']} ({result['regions']} regions, {result['regions_route']}; "
             f"{result['target_points']} target points; {result['seeds']} seeds; fitness mean ± std, "
             "median seconds)", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for k in counts:
        row = [str(k)]
        if ref:
            row.append(f"{ref['fitness'][k - 1]:.4f}" if k <= len(ref["fitness"]) else "-")
        for m in methods:
            s = result["methods"][m][str(k)]
            row.append(f"{s['fitness_mean']:.4f} ± {s['fitness_std']:.4f} ({s['seconds_median']:.2f} s)")
        lines.append("| " + " | ".join(row) + " |")
    lines += ["", f"Coverage (%) and mean uncertainty (mm², spectral norm of the fused covariance) at "
              f"{result['dense_points']} dense target points", "",
              "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for k in counts:
        row = [str(k)]
        if ref:
            row.append(f"{100 * ref['coverage_dense'][k - 1]:.1f} / {1e6 * ref['uncertainty_dense_m2'][k - 1]:.3f}"
                       if k <= len(ref["coverage_dense"]) else "-")
        for m in methods:
            s = result["methods"][m][str(k)]
            row.append(f"{100 * s['coverage_dense_mean']:.1f} / {1e6 * s['uncertainty_dense_mean_m2']:.3f}")
        lines.append("| " + " | ".join(row) + " |")
    if ref:
        lines += ["", f"Reference: greedy over {ref['candidates']} candidates ({ref['grid']['spacing_m']} m grid, "
                  f"{ref['grid']['angles']}² gimbal angles), {ref['arrangements_scored']} arrangements scored "
                  f"in {ref['seconds']:.1f} s."]
    return "\n".join(lines) + "\n"
