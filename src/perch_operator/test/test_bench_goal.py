"""`perch bench mission`'s goal: the scene as asked, and the up axis passed on as `perch plan` does."""

from __future__ import annotations

import argparse

import pytest


def _args(*argv: str):
    from perch_operator.bench import mission

    parser = argparse.ArgumentParser()
    mission.register(parser.add_subparsers())
    return parser.parse_args(["mission", "--kind", "room", "--scene", "1", *argv])


def test_the_up_axis_reaches_the_goal():
    from perch_operator.bench.mission import build_goal

    goal, source, faces = build_goal(_args("--up", "+z", "--cameras", "3"))
    assert goal.up_axis == "+z" and goal.num_cameras == 3 and goal.auto_accept
    assert source == "room seed 1" and faces == len(goal.mesh.triangles) // 3 > 100
    assert build_goal(_args())[0].up_axis == ""   # the coordinator's input_up_axis


def test_a_malformed_up_axis_is_refused_before_anything_starts():
    from perch_operator.bench.mission import build_goal

    with pytest.raises(ValueError, match="up"):
        build_goal(_args("--up", "sideways"))
