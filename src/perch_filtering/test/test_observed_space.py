"""Observed versus unknown space: a perch over space the scan never saw is refused, with its reason,
by the filter and by the project checker (perch_check); the same wall inside a scanned room is not."""

from __future__ import annotations

import numpy as np
from filtering_scenes import Builder

from perch_common.target import TargetVolume
from perch_filtering.core import FilterConfig, filter_surfaces
from perch_filtering.observed import escape_shares, sphere_directions
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
