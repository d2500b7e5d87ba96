"""Parameters of the perch_operator node (crop, coordinator, operator, waypoints)."""

from __future__ import annotations

from dataclasses import dataclass, field

from perch_operator.crop import CropConfig


@dataclass
class OperatorConfig:
    introspection: bool = field(default=True, metadata={
        "description": "publish service introspection events (requests and replies) of /perch/crop"})
    auto_accept: bool = field(default=False, metadata={
        "description": "accept every proposal without waiting for an operator (unattended runs); "
                       "a goal can also ask for it"})
    exclusion_radius: float = field(default=0.3, metadata={
        "description": "a rejected or failed perch excludes perching within this radius", "unit": "m"})
    approach_distance: float = field(default=0.5, metadata={
        "description": "waypoint approach point: this far in front of the perch along its normal",
        "unit": "m"})
    input_up_axis: str = field(default="auto", metadata={
        "description": "up of a given mesh when the goal names none: auto (estimated; the file format's "
                       "convention when unsure, glTF +y) or +x, -x, +y, -y, +z, -z, 'x y z'. Outputs stay "
                       "in the mesh's frame"})
    clean_given_mesh: bool = field(default=True, metadata={
        "description": "run /perch/clean_mesh on a mesh given by file or message before cropping"})
    optimise_on_full_mesh: bool = field(default=True, metadata={
        "description": "optimise against the uncropped mesh (everything outside the crop still occludes)"})
    service_wait: float = field(default=5.0, metadata={
        "description": "how long to wait for a stage's service to appear before failing", "unit": "s"})
    stage_timeout: float = field(default=300.0, metadata={
        "description": "a stage that does not reply within this time fails the mission", "unit": "s"})
    gone_grace: float = field(default=2.0, metadata={
        "description": "a stage whose service vanished for this long during a call fails the mission",
        "unit": "s"})
    confirm_timeout: float = field(default=600.0, metadata={
        "description": "how long a mission waits for operator decisions (0: until cancelled)", "unit": "s"})
    client_grace: float = field(default=5.0, metadata={
        "description": "a mission whose client left the graph this long ago is aborted (0: never)", "unit": "s"})
    crop: CropConfig = field(default_factory=CropConfig)
