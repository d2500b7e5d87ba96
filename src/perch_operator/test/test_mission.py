"""Mission flow against a scripted stage caller (no ROS graph): order, feedback, results, re-planning."""

import re

import numpy as np
import pytest

from perch_common.frames import Alignment
from perch_common.ros.conversions import mesh_to_msg, xyz
from perch_common.ros.static_transforms import alignment_to_msg
from perch_interfaces import msg as pm
from perch_interfaces import srv
from perch_interfaces.action import PlanPerches
from perch_operator.coordinator.mission import Mission, MissionOptions, replan_slot
from perch_operator.coordinator.proposals import Decision, Status
from perch_operator.coordinator.stages import StageError


def placement_msg(x: float) -> pm.CameraPlacement:
    p = pm.CameraPlacement(region_id=1)
    p.drone_pose.position.x = x
    p.drone_pose.orientation.w = p.camera_pose.orientation.w = 1.0
    return p


class ScriptedStages:
    """Answers each stage like a healthy graph would; `fail` makes one stage raise."""

    def __init__(self, mesh_msg, fail: str | None = None, regions: int = 1, clean_report=None):
        self.mesh_msg, self.fail, self.regions, self.clean_report = mesh_msg, fail, regions, clean_report
        self.requests: list[tuple[str, object]] = []

    def call(self, stage, request, cancelled=lambda: False, progress=None):
        self.requests.append((stage, request))
        if stage == self.fail:
            raise StageError(stage, "failed: boom")
        if stage == "clean":  # aligned like the real node: gravity onto -z, the frame renamed
            alignment = Alignment.from_up(request.mesh.header.frame_id, -xyz(request.gravity))
            from perch_common.ros.conversions import mesh_from_msg

            mesh = mesh_from_msg(request.mesh).transformed(alignment.to_aligned())
            mesh.frame_id = alignment.aligned_frame
            report = self.clean_report
            return srv.CleanMesh.Response(success=True, mesh=mesh_to_msg(mesh), seconds=0.1,
                                          message=report.summary() if report else "",
                                          warnings=report.warnings if report else [],
                                          alignment=alignment_to_msg(alignment))
        if stage == "crop":
            return srv.Crop.Response(success=True, mesh=request.mesh, seconds=0.01,
                                     target=pm.TargetVolume(kind=pm.TargetVolume.KIND_BOX))
        if stage == "segment":
            return srv.Segment.Response(success=True, surfaces=[pm.Surface(id=0)], seconds=0.2)
        if stage == "filter":  # classes the surface a wall; echoes no surfaces (not asked)
            return srv.Filter.Response(success=True, regions=[pm.PerchRegion(id=i) for i in range(self.regions)],
                                       removals=[pm.FilterRemoval(surface_id=0, area_total=3.0, orientation=2.5,
                                                                  perch_window=0.5, surface_class=pm.Surface.CLASS_WALL)],
                                       seconds=0.3)
        if stage == "optimise":
            n = request.num_cameras or 2
            start = 10.0 * len(request.exclusions)
            return srv.Optimise.Response(success=True, placements=[placement_msg(start + i) for i in range(n)],
                                         fitness=0.5, coverage=0.8, mean_uncertainty=0.01, seconds=0.4)
        raise AssertionError(stage)


def options(auto: bool = True) -> MissionOptions:
    return MissionOptions(auto_accept=auto, exclusion_radius=0.3, clean_given_mesh=True, optimise_on_full_mesh=True,
                          confirm_timeout=0.0, up=np.array([0.0, 0.0, 1.0]), frame_id="map")


def run(stages, goal, auto=True):
    feedback, proposals, operators = [], [], []
    mission = Mission(stages, options(auto), 5, lambda *f: feedback.append(f), lambda: False,
                      lambda *ps: proposals.extend((p.id, p.status) for p in ps), operators.append)
    return mission, mission.run(goal), feedback, proposals, operators


@pytest.fixture
def goal(meshes):
    return PlanPerches.Goal(mesh=mesh_to_msg(meshes.room()), num_cameras=2, auto_accept=True, seed=4)


def test_stages_run_in_order_with_rising_feedback_and_times(meshes, goal):
    stages = ScriptedStages(goal.mesh)
    mission, result, feedback, proposals, operators = run(stages, goal)
    assert [s for s, _ in stages.requests] == ["clean", "crop", "segment", "filter", "optimise"]
    assert result.success and len(result.placements) == 2
    assert result.stage_names == ["clean", "crop", "segment", "filter", "optimise", "confirm", "total"]
    np.testing.assert_allclose(result.stage_seconds[:5], [0.1, 0.01, 0.2, 0.3, 0.4])
    fractions = [f for _, f, _ in feedback]
    assert fractions == sorted(fractions) and fractions[0] == 0.0 and fractions[-1] < 1.0
    assert [s for s, _, _ in feedback][:5] == ["clean", "crop", "segment", "filter", "optimise"]
    # Every proposal is published pending, then accepted by the policy; ids start where asked.
    assert proposals == [(5, Status.PENDING), (5, Status.ACCEPTED),
                                                     (6, Status.PENDING), (6, Status.ACCEPTED)]
    optimise = stages.requests[-1][1]
    assert optimise.seed == 4 and optimise.num_cameras == 2 and optimise.mesh.header.frame_id == "map_gravity_aligned"
    assert (result.fitness, result.coverage) == (0.5, 0.8)
    # Neither the crop's kept faces nor the filter's surfaces are asked for; viewers get the
    # segmented surfaces with the classes the filter gave them.
    requests = dict(stages.requests)
    assert not requests["crop"].return_kept_faces and not requests["filter"].return_surfaces
    assert [(s.id, s.surface_class) for s in operators[0].surfaces] == [(0, pm.Surface.CLASS_WALL)]


def test_a_given_meshs_input_frame_is_told_before_it_is_cleaned_and_its_alignment_after(goal):
    """The coordinator draws a given scan (on its view thread) while the clean stage runs: the mission
    tells the input frame once the up axis is settled, before the clean call; the alignment, which
    the clean corrects, after it."""
    events = []

    class Recording(ScriptedStages):
        def call(self, stage, request, cancelled=lambda: False, progress=None):
            events.append(stage)
            return super().call(stage, request, cancelled, progress)

    goal.mesh.header.frame_id = "scan"
    mission = Mission(Recording(goal.mesh), options(), 1, lambda *f: None, lambda: False, lambda *ps: None,
                      lambda o: None, on_alignment=lambda a: events.append(("aligned", a.input_frame)),
                      on_input_frame=lambda frame: events.append(("input frame", frame)))
    assert mission.run(goal).success
    assert events[:4] == [("input frame", "scan"), "clean", ("aligned", "scan"), "crop"]


def test_a_failing_stage_ends_the_mission_with_its_name(goal):
    stages = ScriptedStages(goal.mesh, fail="segment")
    mission = Mission(stages, options(), 1, lambda *f: None, lambda: False, lambda *ps: None, lambda o: None)
    with pytest.raises(StageError, match=r"^stage segment \(/perch/segment\): failed: boom"):
        mission.run(goal)
    assert mission.stage_names == ["clean", "crop"]


def test_no_regions_is_a_clear_error(goal):
    stages = ScriptedStages(goal.mesh, regions=0)
    with pytest.raises(ValueError, match=r"no perch regions on 1 surface.*orientation 2\.5 m\^2, perch_window 0\.5 m\^2$"):
        run(stages, goal)


def test_a_failure_says_what_the_clean_stage_warned_of(goal):
    """A mesh in unwelded blocks segments into little: the filter's "no perch regions" then says why."""
    from perch_reconstruction.cleaning import CleanReport

    report = CleanReport(faces_in=9, faces_out=9, up_source="gravity",
                         warnings=["removed 3 duplicate or degenerate faces", "the mesh falls apart into fragments: 9 "
                                   "disconnected pieces, the largest 0.06 m^2 (1% of the area)"])
    mission = Mission(ScriptedStages(goal.mesh, regions=0, clean_report=report), options(), 1,
                      lambda *f: None, lambda: False, lambda *ps: None, lambda o: None)
    with pytest.raises(ValueError, match="no perch regions"):
        mission.run(goal)
    assert mission.clean_hint() == ("; the clean stage warned: removed 3 duplicate or degenerate faces; the mesh falls "
                                    "apart into fragments: 9 disconnected pieces, the largest 0.06 m^2 (1% of the area)")
    quiet = Mission(ScriptedStages(goal.mesh, regions=0, clean_report=CleanReport(9, 9)), options(), 1,
                    lambda *f: None, lambda: False, lambda *ps: None, lambda o: None)
    with pytest.raises(ValueError):
        quiet.run(goal)
    assert quiet.clean_hint() == ""


def test_finding_nothing_on_an_estimated_up_axis_names_it_and_the_option(goal):
    """A crop, segment, filter or optimise finding nothing may be a room turned on its side: when the
    up axis was estimated from the mesh, the failure says which axis it was and how to give another."""
    goal.up_axis = "auto"
    for stages, error in ((ScriptedStages(goal.mesh, regions=0), ValueError),
                          (ScriptedStages(goal.mesh, fail="segment"), StageError)):
        mission = Mission(stages, options(), 1, lambda *f: None, lambda: False, lambda *ps: None, lambda o: None)
        with pytest.raises(error) as failed:
            mission.run(goal)
        assert re.fullmatch(r"; the up axis was estimated from the mesh as \+z \(confidence \d\.\d\d\): if that is "
                            r"not up, pass --up AXIS \(perch mesh info FILE shows the evidence\)",
                            mission.up_hint(failed.value)), mission.up_hint(failed.value)
    # Not for a failure before the alignment, nor when the axis was given.
    mission = Mission(ScriptedStages(goal.mesh, fail="clean"), options(), 1, lambda *f: None, lambda: False,
                      lambda *ps: None, lambda o: None)
    with pytest.raises(StageError) as failed:
        mission.run(goal)
    assert mission.up_hint(failed.value) == ""
    goal.up_axis = "+z"
    mission = Mission(ScriptedStages(goal.mesh, regions=0), options(), 1, lambda *f: None, lambda: False,
                      lambda *ps: None, lambda o: None)
    with pytest.raises(ValueError) as failed:
        mission.run(goal)
    assert mission.up_hint(failed.value) == ""
    # An unsure estimate's fallback (a mission reviewed by a person) is named as the file's convention.
    assert Alignment("map", np.eye(3), "file convention", 0.21).up_estimated.startswith(
        "the up axis is the file's convention +z (confidence 0.21): if that is not up, pass --up AXIS")


def test_a_target_outside_the_mesh_is_refused_in_the_frame_it_was_given_in(meshes, goal):
    """The room turned 90 deg about x (-y up): a box centred beyond it is refused with the numbers of
    the mesh's own frame, before any stage (the filter's refusal used the gravity-aligned frame's)."""
    turn = np.eye(4)
    turn[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]
    room = meshes.room().transformed(turn)
    goal.mesh = mesh_to_msg(room)
    goal.up_axis = "-y"
    goal.target = pm.TargetVolume(kind=pm.TargetVolume.KIND_BOX)
    goal.target.box.pose.position.x, goal.target.box.pose.position.y, goal.target.box.pose.position.z = 10.0, 1.0, -1.0
    goal.target.box.pose.orientation.w = 1.0
    goal.target.box.size.x = goal.target.box.size.y = goal.target.box.size.z = 1.0
    stages = ScriptedStages(goal.mesh)
    lo, hi = (np.round(b, 3).tolist() for b in room.bounds())
    with pytest.raises(ValueError, match=re.escape(f"the target's centre [10.0, 1.0, -1.0] lies outside the scanned "
                                                   f"room (the mesh spans {lo} .. {hi} in its own frame")):
        run(stages, goal)
    assert stages.requests == []


def test_goal_needs_exactly_one_source(goal):
    goal.mesh_path = "/somewhere/room.ply"
    with pytest.raises(ValueError, match="exactly one of mesh_path, bag_path or mesh"):
        run(ScriptedStages(goal.mesh), goal)


def test_bag_goal_reconstructs_instead_of_cleaning(goal):
    class Reconstructing(ScriptedStages):
        def call(self, stage, request, cancelled=lambda: False, progress=None):
            if stage == "reconstruct":
                self.requests.append((stage, request))
                return srv.Reconstruct.Response(success=True, mesh=self.mesh_msg, seconds=2.0,
                                                alignment=alignment_to_msg(Alignment("world", np.eye(3))))
            return super().call(stage, request, cancelled)

    stages = Reconstructing(goal.mesh)
    bag_goal = PlanPerches.Goal(bag_path="/data/kitchen.mcap", auto_accept=True)
    _, result, _, _, _ = run(stages, bag_goal)
    assert [s for s, _ in stages.requests][:2] == ["reconstruct", "crop"]
    assert stages.requests[0][1].bag_path == "/data/kitchen.mcap" and result.success


DAMAGE = "damaged bag, read as far as it goes (54 frame(s) recovered, 6 lost): chunk at byte 5339176 fails its CRC"


class DamagedBagStages(ScriptedStages):
    """Stages whose reconstruction read a damaged bag: its reply says what was lost."""

    def call(self, stage, request, cancelled=lambda: False, progress=None):
        if stage == "reconstruct":
            return srv.Reconstruct.Response(success=True, mesh=self.mesh_msg, seconds=2.0,
                                            message=f"900 faces from 54 of 54 frames; {DAMAGE}",
                                            alignment=alignment_to_msg(Alignment("world", np.eye(3))))
        return super().call(stage, request, cancelled)


def test_what_a_damaged_bag_lost_is_in_the_result_and_the_feedback(goal):
    """It used to be only in the reconstruct node's log (bad-input finding 3)."""
    _, result, feedback, _, _ = run(DamagedBagStages(goal.mesh), PlanPerches.Goal(bag_path="/k.mcap", auto_accept=True))
    assert result.success and f"perch(es) accepted; {DAMAGE}" in result.message
    assert any(DAMAGE in str(f) for f in feedback)


def test_a_failed_mission_from_a_damaged_bag_says_what_the_bag_lost(goal):
    """A damaged bag's mission that failed later (the filter found nothing on a partial scan) used to say
    nothing of the damage."""
    from perch_operator.coordinator.node import OperatorNode

    mission = Mission(DamagedBagStages(goal.mesh, fail="filter"), options(True), 5, lambda *f: None,
                      lambda: False, lambda *ps: None, lambda *o: None)
    with pytest.raises(StageError) as failure:
        mission.run(PlanPerches.Goal(bag_path="/k.mcap", auto_accept=True))
    result = OperatorNode._failed(mission, str(failure.value))
    assert not result.success and result.message == f"{failure.value}; {DAMAGE}"


def test_replan_keeps_the_other_slots_and_sends_every_exclusion(goal):
    stages = ScriptedStages(goal.mesh)
    _, _, _, _, [operator] = run(stages, goal)
    book = operator.book
    first, second = book.current()
    book.decide(second.id, Decision.FAILED_IN_FLIGHT, "slipped")
    replacement = replan_slot(stages, operator, second.slot)
    request = stages.requests[-1][1]
    assert request.num_cameras == 1 and request.seed == 4
    assert len(request.fixed) == 1 and request.fixed[0].drone_pose.position.x == pytest.approx(0.0)
    assert len(request.exclusions) == 1 and request.exclusions[0].radius == pytest.approx(0.3)
    assert request.exclusions[0].center.x == pytest.approx(1.0)
    assert replacement.slot == second.slot and replacement.status == Status.PENDING
    assert book.open_slots() == [second.slot]


def test_waiting_for_decisions_ends_on_cancel_and_on_timeout(goal):
    from perch_operator.coordinator.stages import MissionCancelled

    goal.auto_accept = False
    calls = {"n": 0}

    def cancelled() -> bool:
        calls["n"] += 1
        return calls["n"] > 2  # cancel while the proposals wait

    mission = Mission(ScriptedStages(goal.mesh), options(auto=False), 1, lambda *f: None, cancelled,
                      lambda *ps: None, lambda o: None)
    with pytest.raises(MissionCancelled, match="waiting for operator decisions"):
        mission.run(goal)
    patient = options(auto=False)
    patient.confirm_timeout = 0.3
    mission = Mission(ScriptedStages(goal.mesh), patient, 1, lambda *f: None, lambda: False, lambda *ps: None,
                      lambda o: None)
    with pytest.raises(TimeoutError, match=r"no operator decision on proposal\(s\) \[1, 2\] within 0.3 s"):
        mission.run(goal)


def test_mesh_path_is_loaded_by_the_coordinator_and_cleaned_along_minus_up(meshes, tmp_path):
    from perch_common.mesh import save_mesh

    path = save_mesh(tmp_path / "room.ply", meshes.room())
    stages = ScriptedStages(None)
    _, result, _, _, _ = run(stages, PlanPerches.Goal(mesh_path=str(path), auto_accept=True))
    stage, clean = stages.requests[0]
    assert stage == "clean" and len(clean.mesh.triangles) == 3 * meshes.room().num_faces
    assert (clean.gravity.x, clean.gravity.y, clean.gravity.z) == (0.0, 0.0, -1.0)
    assert clean.mesh.header.frame_id == "map_gravity_aligned" and result.success


@pytest.mark.parametrize("units", ["millimetres", "utm"])
def test_a_mesh_path_needing_a_scale_or_shift_is_refused_with_what_a_goal_can_do(meshes, tmp_path, units):
    from perch_common.mesh import Mesh, MeshError, save_mesh

    room = meshes.room()
    vertices = room.vertices * 1000 if units == "millimetres" else room.vertices + [452113.25, 5201244.5, 312.0]
    path = tmp_path / "room.obj"   # text: every decimal of the UTM coordinates kept
    save_mesh(path, Mesh(vertices, room.faces))
    stages = ScriptedStages(None)
    hint = "--scale 0.001" if units == "millimetres" else "--shift="
    with pytest.raises(MeshError, match=rf"{hint}.*A goal's mesh_path is read as it is .* the goal's mesh field"):
        run(stages, PlanPerches.Goal(mesh_path=str(path), auto_accept=True))
    assert stages.requests == []   # refused before any stage was called


def rotated_room_goal(meshes, orientation: str = "y-down", **fields):
    from perch_common.scan_orientations import oriented

    room, up, transform = oriented(meshes.room(), np.array([0.0, 0.0, 1.0]), orientation)
    room.frame_id = "scan"
    return PlanPerches.Goal(mesh=mesh_to_msg(room), num_cameras=2, auto_accept=True, **fields), up, transform


def test_a_rotated_mesh_is_planned_gravity_aligned_and_answered_in_its_own_frame(meshes):
    from perch_common.ros.conversions import pose_matrix
    from perch_common.ros.static_transforms import alignment_from_msg
    from perch_common.target import TargetVolume
    from perch_operator.cli.plan import parse_target

    goal, up, _ = rotated_room_goal(meshes)
    goal.target = parse_target("box:1,-1,0.5,1,1,1")  # in the mesh's (input) frame
    stages = ScriptedStages(goal.mesh)
    aligned = []
    mission = Mission(stages, options(), 1, lambda *f: None, lambda: False, lambda *ps: None, lambda o: None,
                      on_alignment=aligned.append)
    result = mission.run(goal)
    clean = stages.requests[0][1]
    # Cleaned after aligning: the mesh arrives gravity-aligned, gravity along -z.
    assert clean.mesh.header.frame_id == "scan_gravity_aligned" and xyz(clean.gravity).tolist() == [0, 0, -1]
    alignment = alignment_from_msg(result.alignment)
    assert result.alignment.header.frame_id == "scan" and result.alignment.child_frame_id == "scan_gravity_aligned"
    assert aligned and aligned[0].input_frame == "scan"
    np.testing.assert_allclose(alignment.rotation @ up, [0, 0, 1], atol=1e-9)
    # The crop got the target in the gravity-aligned frame ...
    crop = dict(stages.requests)["crop"]
    box = TargetVolume(center=xyz(crop.target.box.pose.position), size=xyz(crop.target.box.size))
    np.testing.assert_allclose(box.center, alignment.rotation @ [1, -1, 0.5], atol=1e-9)
    # ... and the placements (the scripted optimiser puts drone i at x = i, aligned) come back in the input frame.
    for i, placement in enumerate(result.placements):
        pose = pose_matrix(placement.drone_pose)
        np.testing.assert_allclose(pose[:3, 3], alignment.rotation.T @ [i, 0, 0], atol=1e-6)
        np.testing.assert_allclose(pose[:3, :3], alignment.rotation.T, atol=1e-6)


def test_a_given_up_axis_the_mesh_contradicts_fails_the_mission_clearly(meshes):
    from perch_common.up_axis import UpAxisError

    goal, _, _ = rotated_room_goal(meshes, up_axis="+y")
    stages = ScriptedStages(goal.mesh)
    with pytest.raises(UpAxisError, match=r"^--up \+y contradicts the mesh: furniture tops face down along it\. "
                                          r"The mesh suggests up -y .*: pass --up -y \(or --up auto\)$"):
        Mission(stages, options(), 1, lambda *f: None, lambda: False, lambda *ps: None, lambda o: None).run(goal)
    assert stages.requests == []  # nothing ran on a misread mesh
    goal.up_axis = "-y"
    assert Mission(ScriptedStages(goal.mesh), options(), 1, lambda *f: None, lambda: False, lambda *ps: None,
                   lambda o: None).run(goal).success


def test_surfaces_under_review_are_shown_in_the_input_frame(meshes):
    goal, up, _ = rotated_room_goal(meshes, review_surfaces=1)

    class FloorSurface(ScriptedStages):
        def call(self, stage, request, cancelled=lambda: False, progress=None):
            if stage == "segment":  # a floor in the gravity-aligned frame: normal +z
                surface = pm.Surface(id=7, area=4.0)
                surface.frame.normal.z = surface.frame.axis_u.x = surface.frame.axis_v.y = 1.0
                surface.frame.origin.z = 0.5
                return srv.Segment.Response(success=True, surfaces=[surface], seconds=0.2)
            return super().call(stage, request, cancelled)

    shown = []
    mission = Mission(FloorSurface(goal.mesh), options(), 1, lambda *f: None, lambda: False, lambda *ps: None,
                      lambda o: None, review=lambda surfaces, opened: shown.extend(surfaces) or opened(1) or set())
    assert mission.run(goal).success
    assert [s.id for s in shown] == [7]
    np.testing.assert_allclose(xyz(shown[0].frame.normal), up, atol=1e-9)  # the floor faces the true up
    np.testing.assert_allclose(xyz(shown[0].frame.origin), 0.5 * up, atol=1e-9)
    # the filter still got the surface in the gravity-aligned frame
    assert dict(mission.caller.requests)["filter"].surfaces[0].frame.normal.z == 1.0


def test_a_room_in_feet_stops_an_auto_accepted_mission_and_is_flagged_in_a_reviewed_one():
    """Hunt 5: a scan in feet read as metres (9 m tall, its tables 2.4 m high) was planned without a word and
    every perch was unsafe in true metres. Its furniture says so; without a reviewer the mission stops."""
    from perch_common.mesh import Mesh, MeshError
    from perch_common.scene_generator import generate_scene

    room = generate_scene(1, "room").mesh
    in_feet = Mesh(room.vertices / 0.3048, room.faces)
    goal = PlanPerches.Goal(mesh=mesh_to_msg(in_feet), num_cameras=2, auto_accept=True, seed=4, up_axis="+z")
    stages = ScriptedStages(goal.mesh)
    with pytest.raises(MeshError, match=r"^the mesh is \d+\.\d m tall and its furniture tops stand \d\.\d m above its "
                                        r"floor .* suggests it is in feet .*: pass --scale 0\.3048 if it is in feet, or "
                                        r"run without --auto-accept to review every proposal$"):
        run(stages, goal)
    assert stages.requests == []   # nothing ran on it
    from perch_operator.coordinator.stages import MissionCancelled

    goal.auto_accept = False   # reviewed: each proposal says the unit is in doubt
    proposed = []
    mission = Mission(ScriptedStages(goal.mesh), options(auto=False), 1, lambda *f: None, lambda: bool(proposed),
                      lambda *ps: proposed.extend(ps), lambda o: None)
    with pytest.raises(MissionCancelled):
        mission.run(goal)
    assert proposed and all(p.reason.startswith("unit unconfirmed: the mesh is") for p in proposed)
    in_metres = PlanPerches.Goal(mesh=mesh_to_msg(room), num_cameras=2, auto_accept=True, seed=4, up_axis="+z")
    mission, result, *_ = run(ScriptedStages(in_metres.mesh), in_metres)
    assert result.success and not any("unit" in n for n in mission.notes)
