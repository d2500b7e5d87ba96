"""The placement searches, one module each, and METHODS: the registry `optimise` picks from."""

from __future__ import annotations

from typing import Callable

from perch_placement.config import METHOD_NAMES
from perch_placement.search.baselines import greedy_grid, greedy_random
from perch_placement.search.celf import celf
from perch_placement.search.context import SearchContext, SearchOutcome
from perch_placement.search.greedy_pso import greedy_pso
from perch_placement.search.naive import naive_pso

# Every method places k cameras on top of the context's committed ones.
METHODS: dict[str, Callable[[SearchContext, int], SearchOutcome]] = {
    "pso": greedy_pso,
    "celf": celf,
    "random": greedy_random,
    "grid": greedy_grid,
    "naive": naive_pso,
}
if tuple(METHODS) != METHOD_NAMES:  # the parameter's choices come from METHOD_NAMES
    raise ImportError("perch_placement: METHODS and config.METHOD_NAMES disagree")

__all__ = ["METHODS", "SearchContext", "SearchOutcome"]
