"""The up estimate on rotated worlds: shared real scans and generated rooms in six orientations,
three file formats; the choice of an up axis from the user's setting (auto, given, contradicted)."""

import numpy as np
import pytest

from perch_common.mesh import Mesh, load_mesh, save_mesh
from perch_common.scan_orientations import ORIENTATIONS, REAL_SCANS, oriented
from perch_common.scene_generator import generate_scene
from perch_common.up_axis import UpAxisError, choose_up, estimate_mesh_up, file_convention


def angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.fixture(scope="module")
def real_scans():
    from perch_common.data import shared_file

    found = {name: shared_file("meshes", name) for name in REAL_SCANS}
    if not all(found.values()):
        pytest.skip("../shared/data/meshes is absent (real scans are optional)")
    return {name: load_mesh(path) for name, path in found.items()}


@pytest.mark.parametrize("orientation", list(ORIENTATIONS))
def test_real_scans_up_within_3_degrees_right_sign(real_scans, orientation):
    for name, mesh in real_scans.items():
        rotated, true_up, _ = oriented(mesh, REAL_SCANS[name], orientation)
        estimate = estimate_mesh_up(rotated)
        assert angle_deg(estimate.up, true_up) < 3.0, (name, orientation, estimate.evidence())
        assert estimate.confident, (name, orientation, estimate.confidence, estimate.evidence())
        facing = next(v for v in estimate.votes if v.name == "furniture tops face up")
        assert facing.vote > 0.5  # the evidence is stated along the chosen up


@pytest.mark.parametrize("orientation", list(ORIENTATIONS))
def test_real_scans_are_aligned_alike_in_every_orientation(real_scans, orientation):
    """Each rotated copy, as float32 like every mesh message, aligns onto its original's aligned frame to
    float32 rounding (the stages then see one room): the 20k-face sample and the axes' refinement do
    not depend on the orientation. Once a sample drawn by area and a hard-window refinement left 5e-5 m
    (ICL living room, tilt-25) and 3e-3 m (apartment) between copies, and a different plan."""
    for name, mesh in real_scans.items():
        native = Mesh(mesh.vertices.astype(np.float32), mesh.faces)
        rotated, _, transform = oriented(native, REAL_SCANS[name], orientation)
        rotated = Mesh(rotated.vertices.astype(np.float32), rotated.faces)
        expected = native.vertices @ estimate_mesh_up(native).aligned_rotation().T
        aligned = rotated.vertices @ estimate_mesh_up(rotated).aligned_rotation().T
        assert np.abs(aligned - expected).max() < 2e-6, (name, orientation)  # float32: 4.8e-7 m at 4 m


def test_icl_office_sign_does_not_follow_the_larger_ceiling(real_scans):
    """The office's ceiling out-areas its floor: the end-plane vote is wrong there and must be outvoted."""
    estimate = estimate_mesh_up(real_scans["icl_office_kt2.obj"])
    assert angle_deg(estimate.up, [0, -1, 0]) < 3.0
    end_plane = next(v for v in estimate.votes if v.name == "floor is the more complete end plane")
    assert end_plane.vote < 0 and estimate.confidence > 0.8


@pytest.fixture(scope="module")
def generated_rooms():
    return {kind: generate_scene(3, kind).mesh for kind in ("room", "l_shaped", "apartment")}


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".glb"])
def test_generated_rooms_in_six_orientations_and_three_formats(generated_rooms, tmp_path, suffix):
    for kind, mesh in generated_rooms.items():
        for orientation in ORIENTATIONS:
            rotated, true_up, _ = oriented(mesh, np.array([0.0, 0.0, 1.0]), orientation)
            path = save_mesh(tmp_path / f"{kind}-{orientation}{suffix}", rotated)
            loaded = load_mesh(path)
            assert np.allclose(loaded.bounds(), rotated.bounds(), atol=1e-4), (kind, orientation, suffix)
            estimate = estimate_mesh_up(loaded)
            assert angle_deg(estimate.up, true_up) < 3.0, (kind, orientation, suffix, estimate.evidence())
            assert estimate.confident, (kind, orientation, suffix, estimate.evidence())


def box_room(size=(5.0, 4.0, 2.6)) -> Mesh:
    """An empty closed box, normals inward: a clear vertical but no evidence of which end is up."""
    import trimesh

    box = trimesh.creation.box(extents=size)
    return Mesh(box.vertices, box.faces[:, ::-1])


def test_empty_box_says_the_sign_is_weak_and_auto_falls_back_to_the_convention():
    estimate = estimate_mesh_up(box_room())
    assert abs(estimate.up[2]) > 0.999 and estimate.axis_confidence > 0.9
    assert not estimate.confident and any("weak evidence" in n for n in estimate.notes)
    choice = choose_up("auto", box_room(), file_convention("room.ply"))
    assert choice.source == "file convention" and choice.up.tolist() == [0, 0, 1]
    assert "not confident" in choice.warnings[0] and "--up AXIS" in choice.warnings[0]
    # glTF is +y up: the same box with its vertical along y takes +y from the convention
    y_vertical = box_room((5.0, 2.6, 4.0))
    assert choose_up("auto", y_vertical, file_convention("room.glb")).up.tolist() == [0, 1, 0]
    assert choose_up("auto", y_vertical, file_convention("room.ply")).up @ [0, 1, 0] > 0.999  # axis clear, sign from +z: nearest


def test_an_unsure_estimate_a_few_degrees_off_the_convention_gives_the_convention_exactly():
    """The box tilted by 3 deg: the estimate follows the tilt but is not confident; auto then plans on
    the file's +z exactly, not on the tilted axis (issue 10: fall back to the file's convention)."""
    from scipy.spatial.transform import Rotation

    tilt = np.eye(4)
    tilt[:3, :3] = Rotation.from_euler("x", 3.0, degrees=True).as_matrix()
    tilted = box_room().transformed(tilt)
    estimate = estimate_mesh_up(tilted)
    assert not estimate.confident and 2.5 < angle_deg(np.abs(estimate.up), [0, 0, 1]) < 3.5
    choice = choose_up("auto", tilted, file_convention("room.ply"))
    assert choice.source == "file convention" and choice.up.tolist() == [0, 0, 1]
    assert "not confident" in choice.warnings[0]


def test_file_conventions():
    assert file_convention("scan.GLB") == "+y" and file_convention("a.gltf") == "+y"
    assert file_convention("a.ply") == "+z" and file_convention(None) == "+z"


def test_given_axis_the_mesh_contradicts_stops_with_the_suggested_axis(generated_rooms):
    room, _, _ = oriented(generated_rooms["room"], np.array([0.0, 0.0, 1.0]), "y-down")
    assert choose_up("-y", room).source == "given"
    with pytest.raises(UpAxisError) as upside_down:
        choose_up("+y", room)
    assert "--up +y contradicts the mesh: furniture tops face down along it" in str(upside_down.value)
    assert "pass --up -y" in str(upside_down.value)
    with pytest.raises(UpAxisError, match="no dominant plane lies within 10 deg of it.*pass --up -y"):
        choose_up("1 1 0", room)
    axes = estimate_mesh_up(room).axes
    wall = axes[int(np.argmin(np.abs(axes @ [0, -1, 0])))]
    with pytest.raises(UpAxisError, match="its dominant planes are walls.*pass --up -y"):
        choose_up(" ".join(f"{c:.4f}" for c in wall), room)
    assert choose_up("auto", room).source == "estimate"


def test_camera_down_hint_and_recorded_gravity():
    box = box_room()
    hinted = estimate_mesh_up(box, down_hint=np.array([0.1, 0.0, 0.9]))  # cameras' image-down points to +z
    assert hinted.up.tolist() == pytest.approx([0, 0, -1], abs=1e-6)
    assert hinted.confident
    gravity = estimate_mesh_up(box, gravity=np.array([0.0, -9.81, 0.0]))
    assert gravity.source == "gravity" and gravity.up.tolist() == [0, 1, 0]


# --- the real-scan corpus (meshes/ and meshes/scans/MANIFEST.tsv): right, or honest -----------------

@pytest.fixture(scope="module")
def corpus():
    from perch_common.scan_corpus import cases

    found = list(cases())
    if not found:
        pytest.skip("../shared/data/meshes is absent (real scans are optional)")
    return found


def test_every_corpus_scan_in_every_rotation_is_right_or_says_it_cannot_know(corpus):
    """`--up auto` as a user runs it (the file's header counts in its own frame): every confident
    estimate within 3 deg with the right sign; the rest not confident, and an auto-accepted mission
    stops on them naming the axes considered and --up."""
    from perch_common.scan_corpus import estimate_case

    confident = 0
    for name, orientation, mesh, true_up, path, _ in corpus:
        row = estimate_case(mesh, true_up, path)
        if row["confident"]:
            confident += 1
            assert row["right"], (name, orientation, row)
        else:
            with pytest.raises(UpAxisError, match=r"^up axis not confident .*considered .*pass --up AXIS"):
                choose_up("auto", mesh, file_convention(path), require_confident=True)
    assert confident >= 0.7 * len(corpus)  # honest, not useless: 41 of 55 at the time of writing


def _cut_copies(mesh: Mesh, true_up: np.ndarray):
    """(what, part of `mesh`): its halves on either side of the two vertical planes through its bounding
    box's centre, and its four quarters (a scan that stopped part way across the room)."""
    across = np.cross(true_up, [1.0, 0, 0] if abs(true_up[0]) < 0.9 else [0, 1.0, 0])
    across /= np.linalg.norm(across)
    side = (mesh.face_centroids() - mesh.vertices.min(axis=0) / 2 - mesh.vertices.max(axis=0) / 2)
    first, second = side @ across >= 0, side @ np.cross(true_up, across) >= 0
    for what, keep in (("half A", first), ("half B", ~first), ("half C", second), ("half D", ~second),
                       ("quarter 0", first & second), ("quarter 1", ~first & second), ("quarter 2", first & ~second),
                       ("quarter 3", ~first & ~second)):
        yield what, mesh.submesh(keep)


def test_scans_cut_part_way_across_are_rarely_confidently_on_their_side(corpus):
    """Every corpus scan (own frame) cut in halves and quarters: a cut can leave the scan thinner
    across than the room is tall, the estimate's main cue. Those the estimate still calls confident
    must be right, but for the few it cannot tell (the cut's open end looks like a missing
    ceiling). Before the open-end checks (_cut_short) and the conflicting-votes cap, 14 of these 88
    were confident and 90 deg off, and missions on them perched drones on the floor; now 3."""
    from perch_common.scan_corpus import estimate_case

    wrong = []
    for name, orientation, mesh, true_up, path, _ in corpus:
        if orientation != "own":
            continue
        for what, part in _cut_copies(mesh, true_up):
            row = estimate_case(part, true_up, None)
            if row["confident"] and not row["right"]:
                wrong.append((name, what, row["up_error_deg"]))
    assert len(wrong) <= 3, wrong
    assert not any(name == "holo2_vrlab.obj" for name, _, _ in wrong), wrong   # where drones were on the floor


def test_inverted_windings_are_recognised_and_the_sign_is_right(corpus):
    """holo2_room_invnormals has every triangle wound backwards (floor facing -y, ceiling +y)."""
    scans = [c for c in corpus if c[0] == "holo2_room_invnormals.obj"]
    if not scans:
        pytest.skip("holo2_room_invnormals.obj is not in the shared data")
    for name, orientation, mesh, true_up, _, _ in scans:
        estimate = estimate_mesh_up(mesh)
        assert estimate.windings_inverted and estimate.confident, (orientation, estimate.evidence())
        assert angle_deg(estimate.up, true_up) < 3.0, orientation


def test_the_true_up_is_never_refused_and_wrong_axes_are_on_confident_scans(corpus):
    """A given --up is checked against the mesh even when the estimate is unsure; the true up must
    pass on every case, and every other room axis is refused wherever the estimate is confident."""
    for name, orientation, mesh, true_up, path, _ in corpus:
        if orientation not in ("own", "tilt-35"):
            continue   # the other rotations repeat the same geometry; two keep the test short
        convention = file_convention(path)
        estimate = choose_up("auto", mesh, convention).estimate
        assert choose_up(" ".join(f"{c:.6f}" for c in true_up), mesh, convention).source == "given", name
        if not estimate.confident:
            continue
        for axis in estimate.axes:
            for wrong in (axis, -axis):
                if angle_deg(wrong, true_up) < 10.0:
                    continue
                with pytest.raises(UpAxisError, match="contradicts the mesh"):
                    choose_up(" ".join(f"{c:.6f}" for c in wrong), mesh, convention)


def test_plus_y_on_a_z_up_office_is_refused(corpus):
    """The issue's case: `--up +y` on a z-up office gave 5 perches, 3 unsafe. Refused, naming the fix."""
    from perch_common.scan_orientations import oriented

    office = next((mesh for name, orientation, mesh, *_ in corpus
                   if name == "icl_office_kt2.obj" and orientation == "own"), None)
    if office is None:
        pytest.skip("icl_office_kt2.obj is not in the shared data")
    z_up, _, _ = oriented(office, np.array([0.0, -1.0, 0.0]), "z-up")
    with pytest.raises(UpAxisError, match=r"^--up \+y contradicts the mesh: its dominant planes are walls.*"
                                          r"pass --up \+z \(or --up auto\)$"):
        choose_up("+y", z_up)
    assert choose_up("+z", z_up).source == "given"


def test_an_unsure_scan_still_refuses_an_upside_down_axis(corpus):
    """holo2_vrlab: 3.2 m tall and 3.2 m wide, so two room axes tie and the estimate is unsure; the
    evidence along a given axis still counts: upside down (-y), its desk tops face down and sit high."""
    scans = [c for c in corpus if c[0] == "holo2_vrlab.obj" and c[1] in ("own", "tilt-25")]
    if not scans:
        pytest.skip("holo2_vrlab.obj is not in the shared data")
    for name, orientation, mesh, true_up, path, _ in scans:
        assert not estimate_mesh_up(mesh).confident
        with pytest.raises(UpAxisError, match=r"contradicts the mesh: furniture tops face down along it\. "
                                              r"The estimate is not confident .*considered"):
            choose_up(" ".join(f"{c:.6f}" for c in -true_up), mesh, file_convention(path))
        assert choose_up(" ".join(f"{c:.6f}" for c in true_up), mesh, file_convention(path)).source == "given"


def test_unsure_auto_accept_stops_with_the_axes_considered_and_the_option():
    with pytest.raises(UpAxisError) as stopped:
        choose_up("auto", box_room(), file_convention("room.ply"), require_confident=True)
    message = str(stopped.value)
    assert message.startswith("up axis not confident (")
    assert "considered +z (score" in message or "considered -z (score" in message
    assert "pass --up AXIS" in message and "without --auto-accept" in message
    assert "confident (" not in message.replace("not confident (", "")   # never 'confident' and 'weak' at once


def test_a_known_exporter_in_the_header_is_evidence(tmp_path):
    """An OBJ whose header names Unity (y-up): its convention is +y, carried as text with the exporter,
    and it decides an otherwise sign-less box's up; without the header OBJ says nothing (+z default)."""
    from perch_common.file_conventions import FileConvention, file_convention_of

    box = box_room((5.0, 2.6, 4.0))   # vertical along y, no sign evidence
    path = save_mesh(tmp_path / "room.obj", box)
    plain = file_convention(path)
    assert plain == "+z" and not FileConvention.parse(plain).from_exporter
    path.write_text("# Exported from Unity scene\n" + path.read_text())
    assert file_convention_of(path) == FileConvention("+y", "Unity")
    assert file_convention(path) == "+y (exporter: Unity)"
    assert FileConvention.parse(file_convention(path)) == FileConvention("+y", "Unity")
    estimate = choose_up("auto", load_mesh(path), file_convention(path)).estimate
    assert estimate.up @ [0, 1, 0] > 0.999 and estimate.confident
    assert any(v.name == "the file's exporter is y-up" and v.vote > 0 for v in estimate.votes)
    # a name in a group, not a comment, does not count
    other = tmp_path / "chair.obj"
    other.write_text("o unity_chair\n" + save_mesh(tmp_path / "c.obj", box).read_text())
    assert file_convention(other) == "+z"


def test_alignment_says_when_the_up_axis_is_unconfirmed():
    from perch_common.frames import Alignment

    assert Alignment.from_up("map", np.array([0.0, 0.0, 1.0]), "estimate", 0.9).up_unconfirmed == ""
    note = Alignment.from_up("map", np.array([0.0, 1.0, 0.0]), "file convention", 0.2).up_unconfirmed
    assert note.startswith("up axis unconfirmed") and "+y" in note and "--up" in note


@pytest.mark.slow
@pytest.mark.parametrize("floors", [2, 4])
def test_stacked_storeys_up_is_right_and_confident(floors):
    """A multi-storey building (slabs, a stair flight and two shafts through every slab; 0.1 m voxels to
    keep it small): every storey's floor and ceiling balance up- and down-facing area between the
    building's ends, so the sign is judged storey by storey (furniture tops and treads face up and
    sit nearer the level below). Right and confident in three orientations (it was 0.01-0.02, once
    on the wrong sign)."""
    scene = generate_scene(0, "multi_storey", floors=floors, resolution=0.1)
    for orientation in ("z-up", "y-down", "tilt-35"):
        rotated, true_up, _ = oriented(scene.mesh, np.asarray(scene.up, np.float64), orientation)
        estimate = estimate_mesh_up(rotated)
        assert angle_deg(estimate.up, true_up) <= 3.0, (floors, orientation, estimate.notes)
        assert estimate.confident, (floors, orientation, estimate.confidence, estimate.notes)
        assert "stacked storeys" in estimate.votes[0].detail, estimate.votes[0].detail


def test_a_header_does_not_outvote_the_scan_it_was_turned_away_from(corpus):
    """A file turned after export keeps its exporter's name: the RealSense corner view turned z-up under a
    y-up exporter's header was 'confident' (1.00) on its horizontal y axis and refused the true --up +z.
    Its own evidence (the floor strip at the other end) disputes the header: not confident, and +z is taken.
    In its own frame header and scan agree, and it stays confident."""
    scans = [c for c in corpus if c[0] == "realsense_corner.ply" and c[1] == "own"]
    if not scans:
        pytest.skip("realsense_corner.ply is not in the shared data")
    _, _, mesh, true_up, _, _ = scans[0]
    header = "+y (exporter: Polycam)"
    assert choose_up("auto", mesh, header).estimate.confident
    turned, up, _ = oriented(mesh, true_up, "z-up")
    estimate = choose_up("auto", turned, header).estimate
    assert not estimate.confident and angle_deg(estimate.up, up) > 80
    assert any(n.startswith("conflicting: the file's exporter is y-up, but the scan's own evidence") for n in estimate.notes)
    assert choose_up("+z", turned, header).source == "given"


def test_a_refused_axis_is_never_the_one_the_hint_suggests(corpus):
    """The ICL living room (true up -y) under a y-up exporter's header: unsure, and the hint names -y, the axis
    the check lets through; before, it named +y, which `--up +y` then refused suggesting +y again."""
    scans = [c for c in corpus if c[0] == "icl_livingroom_kt2.obj" and c[1] == "own"]
    if not scans:
        pytest.skip("icl_livingroom_kt2.obj is not in the shared data")
    mesh = scans[0][2]
    header = "+y (exporter: Scaniverse)"
    with pytest.raises(UpAxisError, match=r"^up axis not confident .* \(e\.g\. --up -y if that is up"):
        choose_up("auto", mesh, header, require_confident=True)
    with pytest.raises(UpAxisError, match=r"^--up \+y contradicts the mesh: furniture tops face down along it\. "
                                          r"The estimate is not confident .*: pass the true up, e\.g\. --up -y if"):
        choose_up("+y", mesh, header)
    assert choose_up("-y", mesh, header).source == "given"


def mezzanine_room() -> Mesh:
    """A 6 x 5 x 3 m room of closed 10 cm slabs with a mezzanine 2 m up over a third of it, its stairs and a
    post (hunt 3's case): most horizontal faces between floor and ceiling sit in the upper half."""
    import trimesh

    def slab(lo, hi):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))

    w, d, h, t = 6.0, 5.0, 3.0, 0.1
    parts = [slab([0, 0, -t], [w, d, 0]), slab([0, 0, h], [w, d, h + t]), slab([-t, 0, 0], [0, d, h]),
             slab([0, -t, 0], [w, 0, h]), slab([0, d, 0], [w, d + t, h]), slab([w, 0, 0], [w + t, d, h]),
             slab([4, 0, 1.9], [w, d, 2.0]), slab([3.9, 0, 0], [4.0, 1.5, 1.9])]
    parts += [slab([2.0 + 0.2 * k, 3.5, 0], [2.2 + 0.2 * k, 4.5, 0.19 * (k + 1)]) for k in range(10)]
    room = trimesh.util.concatenate(parts)
    return Mesh(room.vertices, room.faces)


def test_a_refused_true_axis_can_be_taken_unchecked():
    """A mezzanine room's evidence says +z would hang things from the floor; its true +z is refused, and
    the refusal says how to insist ('+z!'), which is then taken with a warning naming the contradiction."""
    mesh = mezzanine_room()
    assert not estimate_mesh_up(mesh).confident
    with pytest.raises(UpAxisError, match=r"^--up \+z contradicts the mesh: the horizontal faces between its floor "
                                          r"and ceiling sit in its upper half.*; if \+z is up nonetheless, "
                                          r"--up '\+z!' takes it unchecked$"):
        choose_up("+z", mesh)
    choice = choose_up("+z!", mesh)
    assert choice.source == "given" and choice.up.tolist() == [0.0, 0.0, 1.0]
    assert choice.warnings == ["up axis +z taken as given, unchecked: the mesh contradicts it (the horizontal faces "
                               "between its floor and ceiling sit in its upper half: things would hang from its floor)"]
    assert choose_up("-z!", mesh).warnings == []   # nothing contradicts it: no warning to give


def dropped_ceiling(mesh: Mesh, share: float = 0.6, drop: float = 0.5) -> Mesh:
    """`mesh` (z-up) with its ceiling `drop` metres lower over the last `share` of its x extent, a vertical
    step between the two levels (a bulkhead or dropped ceiling; hunt 5's case), cut into 8 cm edges first."""
    import trimesh

    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=0.08)
    z, x = vertices[:, 2], vertices[:, 0]
    floor, ceiling = np.percentile(z, [1, 99])
    low, high = np.percentile(x, [1, 99])
    top = np.where(x > high - share * (high - low), ceiling - drop, ceiling)
    base = floor + 0.9   # the room below stays as it is; above, heights shrink to the new ceiling
    moved = z > base
    vertices = vertices.copy()
    vertices[moved, 2] = base + (z[moved] - base) * (top[moved] - base) / (ceiling - base)
    return Mesh(vertices, faces)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_dropped_ceiling_is_a_step_of_the_ceiling_not_upside_down_furniture(seed):
    """A ceiling 50 cm lower over 60 % of a room faces down between floor and ceiling, like table tops upside
    down: counted as furniture it turned every generated room's up axis over, 'confident' (0.67-1.00), and
    drones were planned onto the floor. A level that large is a step of a floor or ceiling and is not counted."""
    scene = generate_scene(seed, ("room", "l_shaped", "room")[seed])
    stepped = dropped_ceiling(scene.mesh)
    for orientation in ("z-up", "y-down", "tilt-35"):
        rotated, true_up, _ = oriented(stepped, np.array([0.0, 0.0, 1.0]), orientation)
        estimate = estimate_mesh_up(rotated)
        assert angle_deg(estimate.up, true_up) < 3.0, (orientation, estimate.evidence())
        assert estimate.confident, (orientation, estimate.confidence, estimate.evidence())
        facing = next(v for v in estimate.votes if v.name == "furniture tops face up")
        assert "in levels as large as a floor or ceiling: steps of one, not counted" in facing.detail
