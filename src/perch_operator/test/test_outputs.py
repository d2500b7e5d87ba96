"""Mission outputs without ROS: overview render, HTML report, rerun file, waypoints.yaml, summary table."""

import numpy as np
import pytest
import yaml

from perch_common.target import TargetVolume
from perch_common.transforms import optical_pose_looking_at
from perch_common.types import CameraPlacement
from perch_operator.outputs.mission_data import MissionData, write_waypoints_yaml


@pytest.fixture
def mission(meshes) -> MissionData:
    mesh = meshes.room()
    mesh.vertex_colors = np.full((mesh.num_vertices, 3), 180, np.uint8)
    target = TargetVolume(center=[2.0, 1.5, 0.6], size=[1.5, 1.0, 1.2])
    poses = [optical_pose_looking_at(np.array(p), target.center) for p in [(0.3, 0.3, 2.4), (3.7, 2.7, 2.4)]]
    placements = [CameraPlacement(i, 0, pose, pose, pan=0.1, tilt=-0.2, marginal_gain=0.3, coverage=0.5 + 0.2 * i)
                  for i, pose in enumerate(poses)]
    waypoints = [{"drone_index": i, "proposal_id": 10 + i, "frame_id": "map", "position": [0.3, 0.3, 2.4],
                  "orientation_xyzw": [0, 0, 0, 1], "approach": [0.3, 0.3, 1.9], "pan": 0.1, "tilt": -0.2, "zoom": 1.0}
                 for i in range(2)]
    summary = {"stage_names": ["crop", "optimise", "total"], "stage_seconds": [0.01, 1.5, 2.0],
               "fitness": 0.42, "coverage": 0.7, "mean_uncertainty": 0.0012}
    return MissionData(mesh=mesh, cropped=mesh, target=target, placements=placements,
                       rejected=[(placements[0], "blocked by a lamp")], waypoints=waypoints, summary=summary)


def test_overview_shows_the_floor_from_above_and_marks_cameras(mission):
    from perch_operator.outputs.render import REJECTED, TopView, overview

    image = overview(mission, size=400)
    view = TopView(mission.mesh.bounds(), 400)
    assert image.shape == (view.height, view.width, 3)
    centre = np.round(view.pixels(np.array([[2.0, 1.2, 0.0]]))[0]).astype(int)
    floor_pixel = image[centre[1], centre[0]]
    assert 60 < floor_pixel.mean() < 250  # shaded grey floor seen through the culled ceiling
    outside = image[2, view.width - 3]
    assert outside.tolist() == [255, 255, 255]
    cam = np.round(view.pixels(np.array([[3.7, 2.7, 2.4]]))[0]).astype(int)
    assert image[cam[1], cam[0]].tolist() != floor_pixel.tolist()
    assert (image == np.array(REJECTED, np.uint8)).all(axis=-1).any()


def test_report_has_numbers_images_and_waypoints(mission, tmp_path):
    from perch_operator.outputs.report import write_report

    path = write_report(mission, tmp_path)
    text = path.read_text()
    assert (tmp_path / "report_files" / "overview.png").stat().st_size > 1000
    assert "70.0 %" in text and "0.0012 m²" in text and "<td class='l'>optimise</td><td>1.50</td>" in text
    assert "blocked by a lamp" in text and "(0.30, 0.30, 1.90)" in text
    assert text.count("<tr><td class='l'>") >= 10


def test_rerun_file_is_written(mission, tmp_path):
    from perch_operator.outputs.rerun_log import write_rrd

    path = write_rrd(mission, tmp_path / "run.rrd")
    data = path.read_bytes()
    assert len(data) > 5000 and data[:4] == b"RRF2"


def test_waypoints_yaml_keeps_the_latest_per_drone(mission, tmp_path):
    later = dict(mission.waypoints[0], proposal_id=99, position=[1.0, 2.0, 3.0])
    path = write_waypoints_yaml(tmp_path / "waypoints.yaml", mission.waypoints + [later])
    doc = yaml.safe_load(path.read_text())
    assert [w["proposal_id"] for w in doc["waypoints"]] == [99, 11]
    assert doc["waypoints"][0]["position"] == [1.0, 2.0, 3.0] and doc["frame_id"] == "map"


def test_waypoints_of_a_scaled_or_shifted_mesh_say_how_to_return_to_the_file(mission, tmp_path):
    """A mesh loaded with --scale/--shift: positions are file x scale + shift; waypoints.yaml says so and
    how to go back (overlaid on the file in centimetres they were 100x off); none without them."""
    from perch_operator.outputs.mission_data import scaled_coordinates

    note = scaled_coordinates(0.01, (-452113.25, -5201244.0, 0.0))
    assert note == ("the mesh file's coordinates x 0.01 + [-452113.25, -5201244, 0] m (--scale, --shift): "
                    "(position - [-452113.25, -5201244, 0]) / 0.01 is in the file's")
    doc = yaml.safe_load(write_waypoints_yaml(tmp_path / "w.yaml", mission.waypoints, note).read_text())
    assert doc["coordinates"] == note and list(doc) == ["frame_id", "units", "coordinates", "waypoints"]
    assert scaled_coordinates(1.0, None) == ""
    assert "coordinates" not in yaml.safe_load(write_waypoints_yaml(tmp_path / "v.yaml", mission.waypoints).read_text())


def test_summary_table_lists_scores_and_stage_times():
    from perch_interfaces.action import PlanPerches
    from perch_interfaces.msg import CameraPlacement as PlacementMsg
    from perch_operator.cli.runner import summary_table

    result = PlanPerches.Result(success=True, coverage=0.815, mean_uncertainty=float("nan"), fitness=0.5,
                                stage_names=["segment", "total"], stage_seconds=[1.234, 5.0],
                                placements=[PlacementMsg(), PlacementMsg()])
    table = summary_table(result)
    assert "| cameras " in table and "|            2 |" in table
    assert "81.5 %" in table and "n/a" in table and "1.23 s" in table and "time total" in table


def test_target_spec_parsing(tmp_path):
    from perch_interfaces import msg as pm
    from perch_operator.cli.plan import parse_target

    assert parse_target(None).kind == pm.TargetVolume.KIND_DEFAULT
    box = parse_target("box:1,2,0.6,2,3,1.2,90")
    assert box.kind == pm.TargetVolume.KIND_BOX and box.box.size.y == 3.0
    assert box.box.pose.orientation.z == pytest.approx(np.sqrt(0.5))
    with pytest.raises(ValueError, match="CX,CY,CZ,SX,SY,SZ"):
        parse_target("box:1,2,3")


def test_a_footprint_target_is_read_with_the_meshs_scale_and_shift(tmp_path):
    from perch_operator.cli.plan import parse_target

    footprint = tmp_path / "site_target.obj"   # a 2 m x 1 m footprint in millimetres, in UTM coordinates
    corners = (np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]]) + [450000, 5200000, 300]) * 1000
    footprint.write_text("".join(f"v {x:.0f} {y:.0f} {z:.0f}\n" for x, y, z in corners) + "f 1 2 3\nf 1 3 4\n")
    target = parse_target(f"{footprint}:1.5", 0.001, (-450000.0, -5200000.0, -300.0))
    assert np.allclose(np.reshape(target.footprint.vertices, (-1, 3)), [[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]])
    assert target.height == pytest.approx(1.5)
    # The same footprint in metres read with the millimetre mesh's --scale: 2 mm across, refused with the fix.
    metres = tmp_path / "target_in_metres.obj"
    metres.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in corners / 1000 - [450000, 5200000, 300])
                      + "f 1 2 3\nf 1 3 4\n")
    with pytest.raises(ValueError, match=r"the footprint is 0\.00224 m across, smaller than anything to watch; it is "
                                         r"read with the mesh's --scale 0\.001: give it in the mesh file's units"):
        parse_target(f"{metres}:1.2", 0.001)


def test_report_explains_removals_evidence_and_shortfall(mission, tmp_path):
    from perch_common.conventions import FILTER_COLOURS, FILTER_NAMES
    from perch_common.types import FilterRemoval, PerchEvidence, PerchRegion, PlaneFrame, Surface, SurfaceClass
    from perch_operator.outputs.report import removal_picture, write_report

    frame = PlaneFrame.from_normal(np.array([2.0, 1.5, 2.5]), np.array([0, 0, -1.0]), np.array([0, 0, 1.0]))
    mission.surfaces = [Surface(id=k, surface_class=SurfaceClass.CEILING if k == 0 else SurfaceClass.WALL,
                                frame=frame, area=a, rms_distance=0.01, mean_color=np.zeros(3),
                                face_indices=np.zeros(0, np.int64), boundary=[])
                        for k, a in enumerate([12.0, 8.0])]
    mission.removals = [FilterRemoval(0, 12.0, recovery_height=4.0, support=6.0, area_kept=2.0),
                        FilterRemoval(1, 8.0, obstacle_clearance=8.0)]
    mission.regions = [PerchRegion(0, 0, SurfaceClass.CEILING, frame, [], mission.mesh, 2.0,
                                   PerchEvidence(0.83, 0.61, 0.925, 0.0123))]
    mission.summary["message"] = "2 perch(es) accepted; 2 of 5 cameras: the only perch region, 2.00 m^2, holds 2 drone(s)"
    text = write_report(mission, tmp_path).read_text()
    assert "2 of 5 cameras: the only perch region, 2.00 m^2" in text
    # Evidence of each camera's region: approach, free fall, support, flatness.
    assert "<td>0.83</td><td>0.61</td><td>92.5 %</td><td>1.2</td>" in text
    # The removal table, largest surface first, in filter order.
    row = "<tr><td class='l'>0</td><td>ceiling</td><td>12.00</td>" + "".join(
        f"<td>{ {'recovery_height': 4.0, 'support': 6.0}.get(n, 0.0):.2f}</td>" for n in FILTER_NAMES) + "<td>2.00</td>"
    assert row in text
    # The picture: the wall's bar is all obstacle_clearance colour, the ceiling's shows support's colour.
    image = removal_picture(mission)
    assert (tmp_path / "report_files" / "removed_by_filter.png").stat().st_size > 1000
    for name in ("support", "recovery_height", "obstacle_clearance"):
        colour = np.array(FILTER_COLOURS[FILTER_NAMES.index(name)][::-1], np.uint8)
        assert (image == colour).all(axis=-1).sum() > 500, name


def test_operator_list_line_shows_the_safety_evidence():
    from perch_interfaces.msg import PerchEvidence, Proposal
    from perch_operator.cli.commands import _proposal_line

    p = Proposal(id=7, evidence=PerchEvidence(approach_clearance=1.0, free_fall=0.62, support_share=0.94,
                                              flatness_rms=0.011))
    line = _proposal_line(p)
    assert "approach 1.00 m, fall 0.62 m, support 94 %, flat 1.1 cm" in line
    assert "evidence not measured" in _proposal_line(Proposal(id=8, evidence=PerchEvidence(
        approach_clearance=-1.0, free_fall=-1.0, support_share=-1.0, flatness_rms=-1.0)))


def test_removal_text_lists_the_largest_surfaces_by_filter(mission):
    from perch_common.conventions import FILTER_NAMES
    from perch_common.types import FilterRemoval, PlaneFrame, Surface, SurfaceClass
    from perch_operator.outputs.report import removal_text

    assert removal_text(mission) == ""  # no filter data recorded
    frame = PlaneFrame.from_normal(np.array([2.0, 1.5, 2.5]), np.array([0, 0, -1.0]), np.array([0, 0, 1.0]))
    mission.surfaces = [Surface(id=k, surface_class=SurfaceClass.WALL, frame=frame, area=a, rms_distance=0.0,
                                mean_color=np.zeros(3), face_indices=np.zeros(0, np.int64), boundary=[])
                        for k, a in enumerate([3.0, 9.0])]
    mission.removals = [FilterRemoval(0, 3.0, support=3.0), FilterRemoval(1, 9.0, recovery_height=7.5, area_kept=1.5)]
    lines = removal_text(mission).splitlines()
    assert all(n in lines[1] for n in FILTER_NAMES)
    assert lines[2].split()[:4] == ["1", "wall", "9.00", "0.00"] and lines[2].split()[-1] == "1.50"
    assert lines[3].split()[FILTER_NAMES.index("support") + 3] == "3.00"
