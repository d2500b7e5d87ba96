"""One validation for every entry: a mission goal gets the stage requests' checks (and their replies),
a mesh named by cache id is checked like one carried in full, and CLI numbers are range-checked
before they become message fields."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from perch_common.request_validation import RequestError, validate_request


@pytest.fixture(scope="module")
def room():
    from perch_common.scene_generator import generate_scene

    return generate_scene(1, "room")


def _mission():
    from perch_operator.coordinator.mission import Mission, MissionOptions

    class NoStages:
        def call(self, stage, request, cancelled, progress=None):
            raise AssertionError(f"a refused goal reached the {stage} stage")

    options = MissionOptions(auto_accept=True, exclusion_radius=0.5, clean_given_mesh=True,
                             optimise_on_full_mesh=False, confirm_timeout=1.0, up=np.array([0.0, 0.0, 1.0]),
                             frame_id="map")
    return Mission(NoStages(), options, 1, lambda *a: None, lambda: False, lambda *a: None, lambda op: None)


def test_a_goal_with_out_of_range_face_indices_is_refused_with_the_stage_reply(room):
    from perch_common.mesh import Mesh
    from perch_common.ros.conversions import mesh_to_msg
    from perch_interfaces.action import PlanPerches

    faces = room.mesh.faces.copy()
    faces[7] = [0, 1, room.mesh.num_vertices + 5]
    goal = PlanPerches.Goal(mesh=mesh_to_msg(Mesh(room.mesh.vertices, faces)), auto_accept=True)
    with pytest.raises(ValueError) as refused:
        _mission().run(goal)
    assert str(refused.value) == (f"invalid goal: mesh.triangles: 1 faces index vertices outside "
                                  f"0..{room.mesh.num_vertices - 1} (first: face 7 = [0, 1, "
                                  f"{room.mesh.num_vertices + 5}])")


def test_integers_that_would_wrap_on_the_wire_are_refused():
    from perch_interfaces.action import PlanPerches

    with pytest.raises(RequestError, match=r"num_cameras = 4294967296: out of range for uint32 \(0\.\.4294967295\)"):
        validate_request(PlanPerches.Goal(num_cameras=2 ** 32))
    with pytest.raises(RequestError, match="num_cameras = 65: at most 64"):
        validate_request(PlanPerches.Goal(num_cameras=65))
    with pytest.raises(RequestError, match="seed = -9223372036854775809: out of range for int64"):
        validate_request(PlanPerches.Goal(seed=-2 ** 63 - 1))


def test_a_huge_target_is_refused_when_the_mesh_comes_by_cache_id(room):
    from perch_common.mesh_cache import PROCESS_CACHE
    from perch_common.ros.conversions import cached_mesh_to_msg, id_only_msg, target_to_msg
    from perch_common.target import TargetVolume
    from perch_interfaces import srv
    from perch_interfaces.action import PlanPerches

    huge = target_to_msg(TargetVolume(center=[0.0, 0.0, 0.0], size=[1000.0, 10.0, 2.0]))
    held = cached_mesh_to_msg(room.mesh)
    try:
        request = srv.Crop.Request(mesh=id_only_msg(held), target=huge)
        with pytest.raises(RequestError, match=r"target is 1000 m across but the mesh only 7\.\d+ m"):
            validate_request(request)
        with pytest.raises(RequestError, match="target is 1000 m across"):
            validate_request(PlanPerches.Goal(mesh=held, target=huge))
        validate_request(srv.Crop.Request(mesh=id_only_msg(held), target=target_to_msg(room.target)))
    finally:
        PROCESS_CACHE.clear()


def test_a_union_target_checks_every_box(room):
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.target import TargetVolume
    from perch_interfaces.action import PlanPerches

    union = target_to_msg(TargetVolume.union([TargetVolume(center=[1, 1, 1], size=[1, 1, 1]),
                                              TargetVolume(center=[2, 2, 1], size=[1, 1, 1])]))
    union.more_boxes[0].size.y = -1.0   # as another node could send it
    with pytest.raises(RequestError, match=r"target.more_boxes\[0\].size.y = -1: box edge lengths must be > 0"):
        validate_request(PlanPerches.Goal(mesh=mesh_to_msg(room.mesh), target=union))
    union.more_boxes[0].size.y = 900.0
    with pytest.raises(RequestError, match="target is 900 m across"):
        validate_request(PlanPerches.Goal(mesh=mesh_to_msg(room.mesh), target=union))


@pytest.mark.parametrize("option,text,message", [
    ("--cameras", "4294967296", "4294967296 is too large; give 0 (the node's default) to 64"),
    ("--cameras", "-1", "-1 is negative"),
    ("--cameras", "2.5", "'2.5' is not an integer"),
    ("--seed", str(2 ** 63), f"{2 ** 63} does not fit a 64-bit seed"),
    ("--timeout", "nan", "nan must be a finite number > 0"),
    ("--timeout", "-5", "-5 must be a finite number > 0"),
    ("--review-surfaces", "-2", "-2 must be an integer from 0 to 4294967295"),   # 0 is no review, not a default
    ("--review-surfaces", str(2 ** 32), f"{2 ** 32} must be an integer from 0 to 4294967295"),
])
def test_cli_numbers_are_range_checked_before_they_become_goal_fields(option, text, message, capsys):
    from perch_operator.cli.plan import register_plan

    parser = argparse.ArgumentParser()
    register_plan(parser.add_subparsers())
    with pytest.raises(SystemExit):
        parser.parse_args(["plan", "--scene", "1", "-o", "out", f"{option}={text}"])
    assert f"argument {option}: {message}" in capsys.readouterr().err
