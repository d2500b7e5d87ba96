"""The browser console (viser): the room, the mission, and the operator's three points of decision.

Scene (the input's frame): the scan (the file's, decimated with its colours, until the graph's own
/perch/scan_marker arrives), the graph's /perch/markers (surfaces by class, perch regions, filter
labels, the target, each proposal's perch and frustum coloured by status), each proposal's drone
camera as a frustum carrying its simulated view, the target and crop boxes with 3D handles (the
centre gizmo moves and turns a box, the corner handle resizes it), the surfaces under review.
Panel: progress (stage, fraction, shortfall), the mission form, the surface review, the proposals
with their views, evidence and buttons, the accepted perches, what each filter removed, and the log
of decisions with who made them. Every browser sees the same state; decisions are serialised.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from perch_common.conventions import FILTER_NAMES
from perch_common.transforms import pose_to_matrix
from perch_console.scene import draw_markers, triangle_mesh, wxyz_of
from perch_console.state import (
    DECISIONS,
    FACES,
    STATUS_NAMES,
    DecisionDesk,
    EditBox,
    evidence_lines,
    floor_hit,
    footprint_triangles,
    removal_table,
    surface_box,
    waypoint_rows,
)

STATUS_RGB = {0: (255, 190, 25), 1: (25, 205, 65), 2: (230, 50, 50), 3: (140, 50, 180)}
CLASS_NAMES = {0: "unknown", 1: "floor", 2: "wall", 3: "ceiling", 4: "intermediate"}
PENDING, ACCEPTED = 0, 1


class Console:
    """The viser server and its panel, fed by a ConsoleGraph (`attach`) and a scan file (`show_scan`)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8080, title: str = "Perch console"):
        import viser

        self.server = viser.ViserServer(host=host, port=port, label=title, verbose=False)
        self.desk = DecisionDesk()
        self.graph = None
        self.goal_source = None            # (mesh message, up convention) of the scan missions start on
        self.first_picture_at: float | None = None
        self._names: dict[int, object] = {}   # client id -> its "your name" field
        self._ui_lock = threading.RLock()
        self._marker_handles: list = []
        self._drone_handles: list = []
        self._review_handles: list = []
        self._crop_editors: dict[int, dict] = {}
        self._shown_proposals = None
        self._scan_handle = None
        self._scan_from_graph = False
        self.server.scene.set_up_direction("+z")
        self.server.on_client_connect(self._on_connect)
        self._build_panel()

    # --- panel --------------------------------------------------------------------------------

    def _build_panel(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large")
        self.status = gui.add_markdown("**Perch console**: waiting for the graph")
        self.progress = gui.add_progress_bar(0.0, animated=False)
        self.shortfall = gui.add_markdown("", visible=False)
        with gui.add_folder("Mission"):
            self.target_center = gui.add_vector3("Target centre", (0.0, 0.0, 1.0), step=0.05)
            self.target_size = gui.add_vector3("Target size", (2.0, 2.0, 1.5), min=(0.05, 0.05, 0.05), step=0.05)
            self.target_shape = gui.add_dropdown("Target shape", ("box", "floor footprint"), initial_value="box",
                                                 hint="a box with handles, or points clicked on the floor")
            self.pick_floor = gui.add_button("Pick floor points", visible=False)
            self.clear_floor = gui.add_button("Clear floor points", visible=False)
            self.footprint_height = gui.add_number("Footprint height", 1.5, min=0.1, max=10.0, step=0.1,
                                                   visible=False)
            self.footprint_md = gui.add_markdown("", visible=False)
            self.crop_on = gui.add_checkbox("Crop to a keep box", False)
            self.crop_center = gui.add_vector3("Keep-box centre", (0.0, 0.0, 1.0), step=0.05, visible=False)
            self.crop_size = gui.add_vector3("Keep-box size", (6.0, 6.0, 3.0), min=(0.05, 0.05, 0.05), step=0.05,
                                             visible=False)
            self.cameras = gui.add_number("Cameras", 4, min=1, max=30, step=1)
            self.review_count = gui.add_number("Review largest surfaces", 0, min=0, max=30, step=1,
                                               hint="0: no surface review; N: approve or reject the N largest")
            self.start = gui.add_button("Start mission", color="green")
            self.start_note = gui.add_markdown("")
        self.review_folder = gui.add_folder("Surface review")
        with self.review_folder:
            self.review_note = gui.add_markdown("_no review open_")
        self.proposals_folder = gui.add_folder("Proposals")
        with self.proposals_folder:
            self.reason = gui.add_text("Reason", "", hint="why a proposal or surface is rejected (sent with it)")
            self.proposals_note = gui.add_markdown("_no proposals yet_")
        self._proposal_handles: list = []
        with gui.add_folder("Accepted perches (waypoints)"):
            self.waypoints_md = gui.add_markdown("_none_")
        with gui.add_folder("Filter removals (m²)", expand_by_default=False):
            self.removals_md = gui.add_markdown("_no filter run yet_")
        with gui.add_folder("Decisions"):
            self.log_md = gui.add_markdown("_none yet_")
        self.start.on_click(self._on_start)
        self.crop_on.on_update(lambda _: self._crop_visible())
        self.target = self._box_editor("target", self.target_center, self.target_size, (40, 210, 210),
                                       lambda: self.target_shape.value == "box")
        self.crop = self._box_editor("crop", self.crop_center, self.crop_size, (240, 150, 30),
                                     lambda: bool(self.crop_on.value))
        self._crop_visible()
        self.picking, self.footprint_points, self._footprint_handle = False, [], None
        self.up, self.floor_height = np.array([0.0, 0.0, 1.0]), 0.0
        self.target_shape.on_update(lambda _: self._target_kind())
        self.pick_floor.on_click(self._on_pick)
        self.clear_floor.on_click(self._clear_footprint)
        self._show_footprint()

    def _on_connect(self, client) -> None:
        with client.gui.add_folder("You", order=-1):
            self._names[client.client_id] = client.gui.add_text("Your name", f"operator {client.client_id}")

    def who(self, event) -> str:
        """The name the deciding browser gave itself."""
        field = self._names.get(event.client_id)
        return (field.value.strip() if field is not None else "") or f"operator {event.client_id}"

    # --- boxes with 3D handles ----------------------------------------------------------------

    def _box_editor(self, name: str, center_field, size_field, rgb, visible=lambda: True) -> dict:
        """A box with 3D handles: the centre gizmo moves and turns it, a handle on each of its six faces
        drags that face (the opposite one stays); the fields follow and can be typed."""
        scene = self.server.scene
        editor = {"name": name, "center": center_field, "size": size_field, "rgb": rgb, "busy": False,
                  "wxyz": np.array([1.0, 0.0, 0.0, 0.0]), "visible": visible, "box": None}
        editor["move"] = scene.add_transform_controls(f"/{name}/move", scale=0.6, depth_test=False)
        editor["faces"] = [
            scene.add_transform_controls(f"/{name}/face_{'xyz'[axis]}{'+' if sign > 0 else '-'}", scale=0.3,
                                         active_axes=tuple(k == axis for k in range(3)), disable_rotations=True,
                                         disable_sliders=True, depth_test=False, line_width=3.5)
            for axis, sign in FACES]

        def from_fields(_=None) -> None:
            self._apply_box(editor, self.box_of(editor))

        def from_move(event) -> None:
            handle = event.target
            if editor["busy"]:
                return
            editor["wxyz"] = np.asarray(handle.wxyz, np.float64)
            box = EditBox(handle.position, editor["size"].value, editor["wxyz"])
            # while dragging, the gizmo in the hand is the browser's: setting it back would fight the drag
            self._apply_box(editor, box, held=None if event.phase == "end" else handle)

        def from_face(event, axis: int, sign: float) -> None:
            if editor["busy"]:
                return
            box = self.box_of(editor).face_moved(axis, sign, event.target.position)
            self._apply_box(editor, box, held=None if event.phase == "end" else event.target)

        center_field.on_update(from_fields)
        size_field.on_update(from_fields)
        editor["move"].on_update(from_move)
        for handle, (axis, sign) in zip(editor["faces"], FACES):
            handle.on_update(lambda event, a=axis, s=sign: from_face(event, a, s))
        from_fields()
        return editor

    def box_of(self, editor: dict) -> EditBox:
        """The box an editor shows now."""
        return EditBox(editor["center"].value, editor["size"].value, editor["wxyz"])

    def _apply_box(self, editor: dict, box: EditBox, held=None) -> None:
        """Show `box` everywhere at once: fields, gizmos (but `held`, the one being dragged) and the
        translucent box."""
        editor["busy"] = True
        try:
            editor["center"].value = tuple(float(v) for v in box.center)
            editor["size"].value = tuple(float(v) for v in box.size)
            editor["wxyz"] = box.wxyz
            if editor["move"] is not held:
                editor["move"].position, editor["move"].wxyz = tuple(box.center), tuple(box.wxyz)
            for handle, (axis, sign) in zip(editor["faces"], FACES):
                if handle is not held:
                    handle.position, handle.wxyz = tuple(box.face(axis, sign)), tuple(box.wxyz)
            if editor["box"] is None:
                editor["box"] = self.server.scene.add_box(
                    f"/{editor['name']}/box", color=editor["rgb"], dimensions=tuple(box.size), opacity=0.22,
                    position=tuple(box.center), wxyz=tuple(box.wxyz), visible=bool(editor["visible"]()),
                    cast_shadow=False, receive_shadow=False)
            else:   # updated in place: one small message per drag step, not a new scene node
                shown = editor["box"]
                shown.dimensions, shown.position, shown.wxyz = tuple(box.size), tuple(box.center), tuple(box.wxyz)
        finally:
            editor["busy"] = False

    def _show_editor(self, editor: dict, on: bool) -> None:
        for handle in (editor["center"], editor["size"], editor["move"], *editor["faces"]):
            handle.visible = on
        if editor["box"] is not None:
            editor["box"].visible = on

    def _remove_editor(self, editor: dict) -> None:
        for handle in (editor["center"], editor["size"], editor["move"], *editor["faces"]):
            handle.remove()
        if editor["box"] is not None:
            editor["box"].remove()

    def _crop_visible(self) -> None:
        self._show_editor(self.crop, bool(self.crop_on.value))

    def _target_kind(self) -> None:
        footprint = self.target_shape.value == "floor footprint"
        self._show_editor(self.target, not footprint)
        for handle in (self.pick_floor, self.clear_floor, self.footprint_height, self.footprint_md):
            handle.visible = footprint
        if not footprint:
            self._picking(False)

    # --- a floor footprint: clicked points on the floor, extruded ----------------------------------

    def _on_pick(self, _event) -> None:
        self._picking(not self.picking)

    def _picking(self, on: bool) -> None:
        """Clicks in the scene add floor points only while picking (a scene click listener also
        changes how the browser reads a click, so it is there only then)."""
        if on and not self.picking:
            self._click_listener = self.server.scene.on_click()(self._on_scene_click)
        elif self.picking and not on:
            self.server.scene.remove_click_callback(self._click_listener)
        self.picking = on
        self.pick_floor.label = "Done picking" if on else "Pick floor points"

    def _on_scene_click(self, event) -> None:
        if not self.picking:
            return
        hit = floor_hit(event.ray_origin, event.ray_direction, self.up, self.floor_height)
        if hit is None:
            return
        with self._ui_lock:
            self.footprint_points.append(hit)
            self._show_footprint()

    def _clear_footprint(self, _event=None) -> None:
        with self._ui_lock:
            self.footprint_points = []
            self._show_footprint()

    def _show_footprint(self) -> None:
        points = np.array(self.footprint_points).reshape(-1, 3)
        if self._footprint_handle is not None:
            self._footprint_handle.remove()
            self._footprint_handle = None
        if len(points):
            closed = np.vstack([points, points[:1]]) if len(points) >= 3 else points
            segments = np.stack([closed[:-1], closed[1:]], axis=1) if len(closed) > 1 else np.stack([points, points], 1)
            self._footprint_handle = self.server.scene.add_line_segments(
                "/target/footprint", points=segments.astype(np.float32), colors=(40, 210, 210), line_width=4.0)
        self.footprint_md.content = (f"{len(points)} floor point(s)" + ("" if len(points) >= 3 else
                                     ": click at least 3 on the floor") if len(points) else
                                     "_press Pick floor points, then click on the floor around the area_")

    def place_boxes(self, vertices: np.ndarray, up: np.ndarray | None = None) -> None:
        """Start the target and keep boxes on the room (the target in its middle, the keep box around it)
        and the view above one corner of it, looking down along `up` (default +z)."""
        self._apply_box(self.target, EditBox.around(vertices, 0.35))
        self._apply_box(self.crop, EditBox.around(vertices, 1.02))
        up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, np.float64) / np.linalg.norm(up)
        # the floor clicks land on: the scan's lowest level along up (1st percentile: stray points below)
        self.up, self.floor_height = up, float(np.percentile(np.asarray(vertices) @ up, 1.0))
        low, high = np.min(vertices, axis=0), np.max(vertices, axis=0)
        center, span = (low + high) / 2, float(np.linalg.norm(high - low))
        side = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        self.server.scene.set_up_direction(tuple(float(v) for v in up))
        camera = self.server.initial_camera
        camera.position = tuple(center + 0.75 * span * up + 0.45 * span * side)
        camera.look_at = tuple(center)
        camera.up = tuple(float(v) for v in up)

    # --- the room -----------------------------------------------------------------------------

    def show_scan(self, mesh, source: str) -> None:
        """The scan file (a perch_common Mesh, input frame), decimated with its colours, until the graph's own."""
        import trimesh

        from perch_operator.coordinator.markers import display_mesh

        shown = display_mesh(mesh)
        colours = shown.vertex_colors if shown.vertex_colors is not None else np.full((shown.num_vertices, 3), 184)
        with self._ui_lock:
            if self._scan_from_graph:
                return
            self._scan_handle = self.server.scene.add_mesh_trimesh(
                "/scan", trimesh.Trimesh(shown.vertices, shown.faces, vertex_colors=colours, process=False))
            self.first_picture_at = self.first_picture_at or time.monotonic()
        self.status.content = f"**Perch console**: {source}, {mesh.num_faces} faces (shown: {shown.num_faces})"

    def _show_graph_scan(self, marker) -> None:
        with self._ui_lock:
            self._scan_from_graph = True
            self._scan_handle = self.server.scene.add_mesh_trimesh("/scan", triangle_mesh(marker))
            self.first_picture_at = self.first_picture_at or time.monotonic()

    # --- the graph ----------------------------------------------------------------------------

    def attach(self, graph) -> None:
        """Listen to a ConsoleGraph (its on_change must call `changed`)."""
        self.graph = graph

    def changed(self, what: str) -> None:
        """Show what the graph changed (called from the graph's threads)."""
        if self.graph is None:
            return
        with self._ui_lock:
            if what == "scan" and self.graph.scan is not None:
                self._show_graph_scan(self.graph.scan)
            elif what == "markers" and self.graph.markers is not None:
                for handle in self._marker_handles:
                    handle.remove()
                # the console draws its own drones and labels, and lists the removals in a table
                shown = [m for m in self.graph.markers.markers if m.ns not in ("proposal_labels", "area_removed")]
                self._marker_handles = draw_markers(self.server.scene, "/mission", shown)
            elif what in ("proposals", "views", "waypoints"):
                self._show_proposals()
            elif what == "review":
                self._show_review()
            elif what == "removals":
                with self.graph.lock:
                    self.removals_md.content = removal_table(self.graph.picture.removals, FILTER_NAMES)
            self._show_progress()

    def _show_progress(self) -> None:
        with self.graph.lock:
            p = self.graph.picture
            stage, fraction, message, shortfall, result = p.stage, p.fraction, p.message, p.shortfall, p.result
        self.progress.value = float(np.clip(fraction * 100, 0, 100))
        text = f"**Stage:** {stage} ({100 * fraction:.0f} %)"
        if message:
            text += f" — {message}"
        if result:
            text += f"\n\n**Result:** {result}"
        self.status.content = text
        self.shortfall.content = f"**Fewer cameras fit:** {shortfall}" if shortfall else ""
        self.shortfall.visible = bool(shortfall)

    # --- (1) start a mission ------------------------------------------------------------------

    def goal(self):
        """The PlanPerches goal the form describes (the scan file's mesh, target box, keep box)."""
        from perch_interfaces import msg as pm
        from perch_interfaces.action import PlanPerches

        if self.goal_source is None:
            raise ValueError("no scan to plan on: start the console with --mesh FILE")
        mesh_msg, convention = self.goal_source

        goal = PlanPerches.Goal(mesh=mesh_msg, num_cameras=int(self.cameras.value), seed=-1, up_axis="auto",
                                up_convention=convention, review_surfaces=int(self.review_count.value))
        if self.target_shape.value == "floor footprint":
            from perch_common.mesh import Mesh
            from perch_common.ros.conversions import mesh_to_msg

            vertices, triangles = footprint_triangles(np.array(self.footprint_points), self.up)
            goal.target = pm.TargetVolume(kind=pm.TargetVolume.KIND_EXTRUDED_FOOTPRINT,
                                          footprint=mesh_to_msg(Mesh(vertices, triangles)),
                                          height=float(self.footprint_height.value))
        else:
            goal.target = pm.TargetVolume(kind=pm.TargetVolume.KIND_BOX, box=oriented_box(self.box_of(self.target)))
        if self.crop_on.value:
            goal.keep_boxes = [oriented_box(self.box_of(self.crop))]
        return goal

    def _on_start(self, event) -> None:
        who = self.who(event)
        self.start.disabled = True
        try:
            goal = self.goal()
            self._shown_proposals = None
            target = (f"footprint of {len(self.footprint_points)} floor points, {self.footprint_height.value:g} m high"
                      if self.target_shape.value == "floor footprint" else self.box_of(self.target).describe())
            # What the goal holds, said back: viser's client drops an edit followed within 50 ms by
            # another, so the page can show a value the console never received.
            planned = (f"{goal.num_cameras} camera(s), "
                       + (f"review of the {goal.review_surfaces} largest surfaces, " if goal.review_surfaces else "")
                       + f"target {target}")
            decision = self.desk.decide(who, "started", "a mission", planned,
                                        lambda: _ok(self.graph.start_mission(goal)))
        except ValueError as exc:
            self.start_note.content = f"**Cannot start:** {exc}"
            self.start.disabled = False
            return
        self.start_note.content = (f"mission started by {who}: {planned}" if decision.success
                                   else f"**{decision.message}**")
        self.start.disabled = False
        with self._ui_lock:
            self._show_log()

    # --- (2) surface review -------------------------------------------------------------------

    def _show_review(self) -> None:
        from perch_common.ros.conversions import frame_from_msg, polygons_from_msg
        from perch_operator.coordinator.markers import surface_outline

        for handle in self._review_handles:
            handle.remove()
        for editor in self._crop_editors.values():
            self._remove_editor(editor)
        self._review_handles, self._crop_editors = [], {}
        with self.graph.lock:
            review = self.graph.picture.review   # its surfaces come in the input's frame (the mission turns them)
        if review is None:
            self.review_note.content = "_no review open_"
            return
        self.review_note.content = (f"**Review {review.review_id}**: the {len(review.surfaces)} largest surfaces, "
                                    "outlined in the room. Approve, reject or crop each (crop: drag the orange "
                                    "box's face handles over the part that is good), then submit.")
        choices = {}
        gui = self.server.gui
        with self.review_folder:
            for surface in review.surfaces:
                kind = CLASS_NAMES.get(surface.surface_class, "?")   # unknown before the filter orients it
                label = f"S{surface.id} {'' if kind == 'unknown' else kind + ' '}{surface.area:.1f} m²"
                choices[surface.id] = gui.add_dropdown(label, ("approve", "reject", "crop"), initial_value="approve")
                self._review_handles.append(choices[surface.id])
                start = surface_box(frame_from_msg(surface.frame), polygons_from_msg(surface.boundary))
                center = gui.add_vector3(f"S{surface.id} crop centre", tuple(start.center), step=0.05, visible=False)
                size = gui.add_vector3(f"S{surface.id} crop size", tuple(start.size), min=(0.05, 0.05, 0.05),
                                       step=0.05, visible=False)
                editor = self._box_editor(f"review/{surface.id}/crop", center, size, (240, 150, 30),
                                          lambda sid=surface.id: choices[sid].value == "crop")
                self._apply_box(editor, start)
                self._show_editor(editor, False)
                self._crop_editors[surface.id] = editor
                choices[surface.id].on_update(
                    lambda _, sid=surface.id: self._show_editor(self._crop_editors[sid], choices[sid].value == "crop"))
                outline = surface_outline(surface, np.eye(4), "", None, (1.0, 1.0, 0.2), "review", 0.05)
                if outline is not None:
                    self._review_handles += draw_markers(self.server.scene, f"/review/{surface.id}", [outline])
                    xyz = np.array([(p.x, p.y, p.z) for p in outline.points])
                    self._review_handles.append(self.server.scene.add_label(
                        f"/review/{surface.id}/label", f"S{surface.id}", position=tuple(xyz.mean(axis=0))))
            submit = gui.add_button("Submit review", color="blue")
            self._review_handles.append(submit)

        def on_submit(event) -> None:
            rejected = [sid for sid, field in choices.items() if field.value == "reject"]
            crops = {sid: oriented_box(self.box_of(self._crop_editors[sid]))
                     for sid, field in choices.items() if field.value == "crop"}
            reason = self.reason.value.strip()
            subject = (f"surface review {review.review_id}" + (f", rejecting {rejected}" if rejected else "")
                       + (f", cropping {sorted(crops)}" if crops else ""))
            self.desk.decide(self.who(event), "decided", subject, reason,
                             lambda: self.graph.call_review(review.review_id, rejected, self._signed(reason, event),
                                                            crops))
            with self._ui_lock:
                self._show_log()

        submit.on_click(on_submit)

    # --- (3) proposals ------------------------------------------------------------------------

    def _show_proposals(self) -> None:
        with self.graph.lock:
            proposals = dict(self.graph.picture.proposals)
            views = dict(self.graph.picture.views)
            fovs = dict(self.graph.picture.view_fov)
        signature = (tuple((i, p.status) for i, p in sorted(proposals.items())), tuple(sorted(views)))
        if signature == self._shown_proposals:
            return
        self._shown_proposals = signature
        for handle in self._proposal_handles + self._drone_handles:
            handle.remove()
        self._proposal_handles, self._drone_handles = [], []
        gui, scene = self.server.gui, self.server.scene
        self.proposals_note.content = "_no proposals yet_" if not proposals else (
            f"{sum(p.status == PENDING for p in proposals.values())} open, "
            f"{sum(p.status == ACCEPTED for p in proposals.values())} accepted; open first")
        ordered = sorted(proposals.values(), key=lambda p: (p.status != PENDING, p.id))
        with self.proposals_folder:
            for p in ordered:
                slot = int(p.placement.drone_index)
                decided = self.desk.by_proposal.get(p.id)
                status = STATUS_NAMES[p.status] if p.status < len(STATUS_NAMES) else "?"
                lines = [f"**#{p.id}** drone {slot}: **{status}**"
                         + (f" by {decided.who}" if decided and p.status != PENDING else "")
                         + (f" ({p.reason})" if p.reason else ""),
                         f"gain {p.placement.marginal_gain:.3f}, coverage {100 * p.placement.coverage:.0f} %, "
                         f"zoom {p.placement.zoom:.1f}",
                         evidence_lines(p.evidence)]
                folder = gui.add_folder(f"Proposal {p.id}", expand_by_default=p.status == PENDING)
                self._proposal_handles.append(folder)
                with folder:
                    gui.add_markdown("  \n".join(lines))
                    if slot in views and p.status != 2:
                        gui.add_image(views[slot], label=f"drone {slot} view", format="jpeg", jpeg_quality=80)
                    if p.status == PENDING:
                        for label, key, colour in (("Accept", "accept", "green"), ("Reject", "reject", "red"),
                                                   ("Failed in flight", "failed", "violet")):
                            button = gui.add_button(f"{label} #{p.id}", color=colour)
                            button.on_click(lambda event, pid=p.id, k=key: self._decide(event, pid, k))
                self._drone_handles += self._drone(scene, p, views.get(slot), fovs.get(slot))
        with self.graph.lock:
            rows = waypoint_rows(self.graph.picture.proposals)
        self.waypoints_md.content = "_none_" if not rows else "\n".join(
            ["| proposal | drone | x | y | z |", "|---|---|---|---|---|"]
            + [f"| {pid} | {drone} | {x:.3f} | {y:.3f} | {z:.3f} |" for pid, drone, x, y, z in rows])

    def _drone(self, scene, p, view, fov) -> list:
        """The drone (a small box on its perch) and its camera frustum carrying the simulated view."""
        rgb = STATUS_RGB.get(p.status, (128, 128, 128))
        drone = p.placement.drone_pose
        handles = [scene.add_box(f"/drones/{p.id}/body", color=rgb, dimensions=(0.25, 0.25, 0.06),
                                 position=(drone.position.x, drone.position.y, drone.position.z),
                                 wxyz=wxyz_of(drone), cast_shadow=False, receive_shadow=False)]
        if p.status == 2:
            return handles   # rejected: its perch only, no view
        camera = pose_to_matrix(p.placement.camera_pose)
        vertical_fov, aspect = fov or (np.radians(58.0), 16 / 9)
        handles.append(scene.add_camera_frustum(
            f"/drones/{p.id}/camera", fov=float(vertical_fov), aspect=float(aspect), scale=0.35, color=rgb,
            image=view, format="jpeg", jpeg_quality=70, position=tuple(camera[:3, 3]),
            wxyz=wxyz_of(p.placement.camera_pose), thickness=0.01))
        handles.append(scene.add_label(f"/drones/{p.id}/label", f"#{p.id}",
                                       position=(drone.position.x, drone.position.y, drone.position.z + 0.2)))
        return handles

    def _decide(self, event, proposal_id: int, key: str) -> None:
        reason = self.reason.value.strip()
        if key == "reject" and not reason:
            reason = "rejected in the console"
        what = {"accept": "accepted", "reject": "rejected", "failed": "marked failed in flight"}[key]
        who = self.who(event)
        self.desk.decide(who, what, f"proposal {proposal_id}", reason,
                         lambda: self.graph.call_confirm(proposal_id, DECISIONS[key], self._signed(reason, event)),
                         proposal_id)
        with self._ui_lock:   # viser's folders take one builder at a time (the graph's threads build too)
            self._shown_proposals = None   # the decider's name goes into the proposal's line
            self._show_proposals()
            self._show_log()

    def _signed(self, reason: str, event) -> str:
        """The reason as sent to the graph, naming the operator (the report then shows who decided)."""
        return f"{reason} [{self.who(event)}]" if reason else f"[{self.who(event)}]"

    def _show_log(self) -> None:
        recent = self.desk.recent()
        self.log_md.content = "_none yet_" if not recent else "  \n".join(d.line() for d in recent)


def oriented_box(box: EditBox):
    """The perch_interfaces/OrientedBox of a box the operator edited (input frame)."""
    from perch_common.ros.conversions import pose_msg, vector_msg
    from perch_interfaces import msg as pm

    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = box.rotation, box.center
    return pm.OrientedBox(pose=pose_msg(pose), size=vector_msg(box.size))


def _ok(error: str) -> tuple[bool, str]:
    return (not error, error or "accepted by the coordinator")


def scan_source(path: Path, scale: float = 1.0, shift: tuple[float, float, float] | None = None):
    """(Mesh, TriangleMesh message, up convention) of a scan file, as `perch plan --mesh` sends it
    (with its --scale and --shift)."""
    from perch_common.mesh import load_mesh
    from perch_common.ros.conversions import mesh_to_msg
    from perch_common.up_axis import file_convention

    mesh = load_mesh(path, scale=scale, shift=shift)
    return mesh, mesh_to_msg(mesh), file_convention(str(path))
