"""An up axis the estimate is not sure of (issue 21): an auto-accepted mission stops before anything is
placed, naming the axes it considered and --up; with an operator every proposal says it is unconfirmed."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import trimesh

from perch_common.mesh import Mesh
from perch_common.ros.conversions import mesh_to_msg
from perch_common.up_axis import UnsureUpError
from perch_interfaces.action import PlanPerches
from perch_operator.coordinator.mission import Mission, replan_slot
from perch_operator.coordinator.proposals import Decision


def _mission_helpers():
    """test_mission's scripted stage caller and options (pytest's importlib mode has no test-module imports)."""
    spec = importlib.util.spec_from_file_location("perch_mission_test_helpers", Path(__file__).with_name("test_mission.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.ScriptedStages, module.options


ScriptedStages, options = _mission_helpers()


def sign_less_box_goal(auto_accept: bool) -> PlanPerches.Goal:
    """An empty closed room: its vertical is clear, but nothing says which end is up."""
    box = trimesh.creation.box(extents=(5.0, 4.0, 2.6))
    mesh = Mesh(box.vertices, box.faces[:, ::-1])
    return PlanPerches.Goal(mesh=mesh_to_msg(mesh), num_cameras=2, auto_accept=auto_accept, up_axis="auto")


def test_auto_accept_stops_before_any_stage_on_an_unsure_up_axis():
    stages = ScriptedStages(None)
    mission = Mission(stages, options(auto=False), 1, lambda *f: None, lambda: False, lambda *ps: None,
                      lambda o: None)
    with pytest.raises(UnsureUpError, match=r"^up axis not confident \(0\.\d\d\): considered [+-]z \(score .*"
                                            r"pass --up AXIS .*or run without --auto-accept"):
        mission.run(sign_less_box_goal(auto_accept=True))
    assert stages.requests == []   # nothing cleaned, cropped or placed


def test_an_operator_mission_goes_on_and_every_proposal_says_the_up_axis_is_unconfirmed():
    goal = sign_less_box_goal(auto_accept=False)
    patient = options(auto=False)
    patient.confirm_timeout = 5.0
    proposed, operators = [], []

    def on_proposal(*proposals):
        proposed.extend(p for p in proposals if p.status.name == "PENDING")
        for p in proposals:   # the operator accepts each one as it comes
            if p.status.name == "PENDING":
                operators[0].book.decide(p.id, Decision.ACCEPT, "looks fine")

    mission = Mission(ScriptedStages(goal.mesh), patient, 1, lambda *f: None, lambda: False, on_proposal,
                      operators.append)
    result = mission.run(goal)
    assert result.success and len(proposed) == 2
    for proposal in proposed:
        assert proposal.reason.startswith("up axis unconfirmed: the estimate was not confident"), proposal.reason
        assert "--up AXIS" in proposal.reason
    assert "not confident" in result.message   # the result says it too
    # a re-planned slot's proposal carries it as well
    replacement = replan_slot(mission.caller, operators[0], 0)
    assert replacement is not None and replacement.reason.startswith("up axis unconfirmed")


def test_a_confident_up_axis_leaves_proposals_without_the_note():
    from perch_common.scene_generator import generate_scene

    goal = PlanPerches.Goal(mesh=mesh_to_msg(generate_scene(3, "room").mesh), num_cameras=2, auto_accept=True)
    proposals = []
    result = Mission(ScriptedStages(goal.mesh), options(), 1, lambda *f: None, lambda: False,
                     lambda *ps: proposals.extend(ps), lambda o: None).run(goal)
    assert result.success and proposals
    assert all("unconfirmed" not in p.reason for p in proposals)
    np.testing.assert_allclose(len(result.placements), 2)
