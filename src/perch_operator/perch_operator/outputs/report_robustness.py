"""The report's robustness section: landing error, k-view coverage, the loss of each camera and the
certificate (the figures perch_placement.robustness and perch_placement.certificate compute)."""

from __future__ import annotations

import html
import math

# Figures of the whole arrangement that both Optimise's reply and PlanPerches' result carry.
ROBUSTNESS_FIELDS = ("expected_fitness", "p5_fitness", "kview_coverage", "worst_coverage_without_one",
                     "mean_coverage_without_one", "worst_kview_coverage_without_one",
                     "mean_kview_coverage_without_one", "coverage_bound")


def _finite(value) -> bool:
    return value is not None and isinstance(value, (int, float)) and math.isfinite(value)


def _pct(value) -> str:
    return f"{100 * value:.1f} %" if _finite(value) else "–"


def _num(value) -> str:
    return f"{value:.4f}" if _finite(value) else "–"


def summary_rows(summary: dict) -> list[tuple[str, str]]:
    """Rows of the arrangement's robustness figures (missing ones, from older recordings, as '–')."""
    coverage, bound = summary.get("coverage"), summary.get("coverage_bound")
    gap = "–"
    if _finite(coverage) and _finite(bound) and bound > 0:
        gap = (f"within {100 * max(0.0, 1 - coverage / bound):.1f} % of the best coverage possible on the candidate "
               f"set (LP bound {100 * bound:.1f} %)" if coverage <= bound + 1e-9 else
               f"coverage beats the candidate set's LP bound ({100 * bound:.1f} %): perches off its grid")
    return [("fitness, nominal", _num(summary.get("fitness"))),
            ("fitness under landing error, expected", _num(summary.get("expected_fitness"))),
            ("fitness under landing error, 5th percentile", _num(summary.get("p5_fitness"))),
            ("k-view coverage", _pct(summary.get("kview_coverage"))),
            ("coverage after losing one camera, worst / mean",
             f"{_pct(summary.get('worst_coverage_without_one'))} / {_pct(summary.get('mean_coverage_without_one'))}"),
            ("k-view coverage after losing one camera, worst / mean",
             f"{_pct(summary.get('worst_kview_coverage_without_one'))} / "
             f"{_pct(summary.get('mean_kview_coverage_without_one'))}"),
            ("certificate (coverage)", gap)]


def camera_rows(placements) -> list[tuple]:
    """Per camera: its contribution (fitness lost without it) nominal, expected and at the 5th
    percentile under landing error, and coverage and k-view coverage without it."""
    return [(str(p.drone_index), _num(p.contribution), _num(p.expected_contribution), _num(p.p5_contribution),
             _pct(p.coverage_without), _pct(p.kview_coverage_without)) for p in placements]


def robustness_section(data, table) -> list[str]:
    """HTML parts of the robustness section; `table(columns, rows, header=True)` renders a table."""
    parts = ["<h2>Robustness</h2>",
             "<p>Landing error: every drone lands off its planned point by a Gaussian offset in the perch plane and "
             "at a Gaussian yaw about the surface normal (perch_placement's <code>landing.*</code> parameters); the "
             "figures are Monte-Carlo over seeded landings shared by every arrangement. k-view coverage: share of "
             "target points seen by at least k cameras with a pair of views at least the configured angle apart "
             "(<code>kview_k</code>, <code>kview_angle_deg</code>). The certificate bounds coverage (fitness is at "
             "most coverage) over the discrete candidate set, by a linear-programming relaxation.</p>",
             table(["", ""], summary_rows(data.summary), header=False)]
    if data.placements:
        parts += ["<h3>Each camera, and the loss of it</h3>", table(
            ["drone", "contribution", "expected under error", "5th percentile", "coverage without it",
             "k-view coverage without it"], camera_rows(data.placements)),
            "<p>Contribution: fitness the arrangement loses when this camera is removed. A camera's figures are "
            "those of the arrangement it was proposed in; the figures above are the last answer's (after a "
            "re-plan, the re-planned set's).</p>"]
    return [p if p.startswith("<") else html.escape(p) for p in parts]
