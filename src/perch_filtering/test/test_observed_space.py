"""Observed versus unknown space: a perch over space the scan never saw is refused, with its reason,
by the filter and by the project checker (perch_check); the same wall inside a scanned room is not."""

from __future__ import annotations

import numpy as np
from filtering_scenes import Builder

from perch_common.raycast import sphere_directions
from perch_common.target import TargetVolume
from perch_filtering.core import FilterConfig, filter_surfaces
from perch_filtering.observed import escape_shares
from perch_filtering.perch_check import check_perches

UP = np.array([0.0, 0.0, 1.0])
TARGET = TargetVolume(center=[1.5, 1.5, 1.0], size=[1.5, 1.5, 1.0])


def fragment_scene(closed: bool = False) -> Builder:
    """A scanned 3 x 3 m floor patch and, 3 m away, a 2 x 1.5 m wall fragment 1.5-3.0 m high facing it
    with nothing scanned below or in front of it (the edge of a partial scan). `closed` puts the
    fragment into a scanned room instead (floor, ceiling and walls all around)."""
    b = Builder()
    if closed:
        b.room("room", [[0, -1], [6, -1], [6, 4], [0, 4]], 3.0)
    else:
        b.quad("floor", [[0, 0, 0], [3, 0, 0], [3, 3, 0], [0, 3, 0]], [0, 0, 1])
    b.quad("fragment", [[5.99, 0.5, 1.5], [5.99, 2.5, 1.5], [5.99, 2.5, 3.0], [5.99, 0.5, 3.0]], [-1, 0, 0])
    return b


def _run(builder: Builder, **overrides):
    names = builder.names()
    surfaces = builder.surfaces(names)
    result = filter_surfaces(builder.mesh(), surfaces, TARGET, UP, FilterConfig(**overrides))
    fragment = surfaces[names.index("fragment")].id
    return result, fragment


def test_escape_share_tells_a_room_from_the_scan_edge():
    closed = fragment_scene(closed=True).mesh()
    open_ = fragment_scene().mesh()
    from perch_common.raycast import RayScene

    inside = np.array([[3.0, 1.5, 1.5], [5.7, 1.5, 2.2]])
    d = sphere_directions(32)
    np.testing.assert_allclose(escape_shares(RayScene(closed), inside, d), 0.0)
    shares = escape_shares(RayScene(open_), inside, d)
    assert shares[1] > 0.5  # in front of the lone fragment most rays leave the model
    assert np.all(shares <= 1.0)


def test_perch_on_a_scan_edge_fragment_is_refused_with_its_reason():
    result, fragment = _run(fragment_scene())
    assert not [r for r in result.regions if r.source_surface == fragment], result.message
    removal = next(r for r in result.removals if r.surface_id == fragment)
    # The observed-space rule removed it (its area counts to the approach's and the fall's filters).
    assert removal.obstacle_clearance + removal.recovery_height > 1.0, removal
    # Without the rule the same fragment carries perches: the rule, not another filter, refused them.
    loose, fragment = _run(fragment_scene(), max_unobserved_share=1.0)
    kept = [r for r in loose.regions if r.source_surface == fragment]
    assert kept and sum(r.area for r in kept) > 0.5
    worst = min(min(r.evidence.approach_observed, r.evidence.fall_observed) for r in kept)
    assert worst < 0.5  # the evidence says how much of it was never observed
    # The project checker refuses a perch in the middle of the fragment and says why.
    verdict = check_perches(fragment_scene().mesh(), [[5.99, 1.5, 2.3]], [[-1.0, 0, 0]], UP)[0]
    assert not verdict.safe
    assert any(r.endswith("% unobserved") and ("fall corridor" in r or "approach prism" in r)
               for r in verdict.reasons), verdict.reasons
    assert verdict.observed_share < 0.5


def test_the_same_wall_inside_a_scanned_room_is_observed():
    result, fragment = _run(fragment_scene(closed=True))
    kept = [r for r in result.regions if r.source_surface == fragment]
    assert kept, result.message
    for r in kept:
        assert r.evidence.approach_observed >= 0.8 and r.evidence.fall_observed >= 0.8, r.evidence
    verdict = check_perches(fragment_scene(closed=True).mesh(), [[5.99, 1.5, 2.3]], [[-1.0, 0, 0]], UP)[0]
    assert verdict.observed_share == 1.0 and not any("unobserved" in r for r in verdict.reasons), verdict.reasons


def half_floor_room() -> Builder:
    """A 6 x 5 x 3 m room with ceiling and walls all round whose floor was scanned only for x < 3 m."""
    b = Builder()
    b.quad("floor", [[0, 0, 0], [3, 0, 0], [3, 5, 0], [0, 5, 0]], [0, 0, 1])
    b.quad("ceiling", [[0, 0, 3], [6, 0, 3], [6, 5, 3], [0, 5, 3]], [0, 0, -1])
    b.quad("wall_south", [[0, 0, 0], [6, 0, 0], [6, 0, 3], [0, 0, 3]], [0, 1, 0])
    b.quad("wall_north", [[0, 5, 0], [6, 5, 0], [6, 5, 3], [0, 5, 3]], [0, -1, 0])
    b.quad("wall_west", [[0, 0, 0], [0, 5, 0], [0, 5, 3], [0, 0, 3]], [1, 0, 0])
    b.quad("wall_east", [[6, 0, 0], [6, 5, 0], [6, 5, 3], [6, 0, 3]], [-1, 0, 0])
    return b


def _kept_x(result, surface_id: int) -> np.ndarray:
    """x of the region outline points on one surface (the south wall runs along x)."""
    pts = [r.frame.to_world(r.polygons[0][0]) for r in result.regions if r.source_surface == surface_id]
    return np.concatenate(pts)[:, 0] if pts else np.zeros(0)


def test_a_fall_with_no_floor_scanned_below_is_refused():
    """Enclosed by walls and ceiling, but with no floor scanned below: the south wall keeps perches
    over the scanned floor only (its fall corridor is 0.35 m either side of a perch), and the checker
    names the fall corridor for a perch over the unscanned half."""
    b = half_floor_room()
    names = b.names()
    surfaces = b.surfaces(names)
    south = surfaces[names.index("wall_south")].id
    target = TargetVolume(center=[1.5, 2.5, 1.0], size=[1.5, 2.0, 1.0])
    result = filter_surfaces(b.mesh(), surfaces, target, UP, FilterConfig())
    x = _kept_x(result, south)
    assert len(x) and x.min() < 2.5, result.message
    assert x.max() <= 3.0 + 0.35 + 0.15, x.max()  # corridor half-width plus one node of the 15 cm grid
    loose = filter_surfaces(b.mesh(), surfaces, target, UP, FilterConfig(max_unobserved_share=1.0))
    assert _kept_x(loose, south).max() > 4.5  # without the rule the wall over the unscanned floor is kept
    verdict = check_perches(b.mesh(), [[5.0, 0.0, 1.8]], [[0, 1.0, 0]], UP)[0]
    assert not verdict.safe and any(r.startswith("fall corridor") and r.endswith("% unobserved")
                                    for r in verdict.reasons), verdict.reasons
    assert verdict.approach_observed == 1.0  # the approach is enclosed; only the fall has no floor under it
    over_floor = check_perches(b.mesh(), [[1.5, 0.0, 1.8]], [[0, 1.0, 0]], UP)[0]
    assert over_floor.observed_share == 1.0, over_floor.reasons
