"""Several target volumes: equal weighting, geometry of the union, and the message round trip."""

from __future__ import annotations

import numpy as np
import pytest

from perch_common.target import TargetVolume


def _boxes():
    small = TargetVolume(center=[0, 0, 1], size=[1, 1, 1])
    large = TargetVolume(center=[10, 0, 1], size=[4, 4, 1])
    return small, large


def test_union_weights_every_volume_equally_whatever_its_size():
    small, large = _boxes()
    union = TargetVolume.union([small, large])
    assert union.volume() == pytest.approx(1 + 16)
    points = union.sample(401, seed=3)
    assert len(points) == 401
    assert small.contains(points).sum() == 201 and large.contains(points).sum() == 200
    np.testing.assert_allclose(union.bounds(), [[-0.5, -2, 0.5], [12, 2, 1.5]])
    np.testing.assert_allclose(union.centroid(), [5, 0, 1])       # mean of the volumes' centres
    assert union.contains(np.array([[0, 0, 1], [10, 1.5, 1], [5, 0, 1]])).tolist() == [True, True, False]
    assert len(union.edges()) == 24
    again = union.sample(401, seed=3)
    np.testing.assert_array_equal(points, again)                  # seeded


def test_union_of_one_is_that_volume_and_unions_flatten():
    small, large = _boxes()
    one = TargetVolume.union([small])
    assert not one.parts and one.volume() == pytest.approx(1)
    nested = TargetVolume.union([TargetVolume.union([small, large]), TargetVolume(center=[0, 5, 1], size=[1, 1, 1])])
    assert len(nested.volumes()) == 3
    with pytest.raises(ValueError, match="at least one volume"):
        TargetVolume.union([])


def test_several_boxes_travel_as_box_plus_more_boxes():
    from perch_common.ros.conversions import target_from_msg, target_to_msg
    from perch_interfaces import msg as pm

    small, large = _boxes()
    msg = target_to_msg(TargetVolume.union([small, large]))
    assert msg.kind == pm.TargetVolume.KIND_BOX and len(msg.more_boxes) == 1
    back = target_from_msg(msg)
    assert [v.volume() for v in back.volumes()] == pytest.approx([1, 16])
    single = target_from_msg(target_to_msg(small))
    assert not single.parts and single.volume() == pytest.approx(1)


def test_cli_target_spec_joins_boxes_with_plus():
    from perch_common.ros.conversions import target_from_msg
    from perch_operator.cli.plan import parse_target

    target = target_from_msg(parse_target("box:0,0,1,1,1,1+box:10,0,1,4,4,1,90"))
    assert len(target.volumes()) == 2 and target.volume() == pytest.approx(17)
    with pytest.raises(ValueError, match="each is a box"):
        parse_target("box:0,0,1,1,1,1+floor")
