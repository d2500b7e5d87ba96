"""Parameters of the perch_operator node (crop, coordinator, operator, waypoints)."""

from __future__ import annotations

from dataclasses import dataclass, field

from perch_common.config import param
from perch_common.transforms import parse_up_axis


@dataclass
class CropConfig:
    """How the default target (the cropped environment's floor area) is found."""

    target_height: float = param(1.2, "default target: height of the volume above the floor", "m", low=0.0)
    floor_angle: float = param(0.35, "faces within this angle of up count as floor candidates", "rad", low=0.0, high=1.5708)
    floor_band: float = param(0.5, "floor candidates lie within this height above the lowest upward face", "m", low=0.0)
    floor_tolerance: float = param(0.08, "faces within this height of the floor level form the floor", "m", low=0.0)
    grid_resolution: float = param(0.05, "cell size of the raster used to outline the floor", "m", low=0.001, high=1.0)
    close_radius: float = param(0.15, "gaps in the floor (e.g. under furniture legs) up to this size are closed", "m", low=0.0)


@dataclass
class OperatorConfig:
    """The perch_operator node's parameters (crop, coordinator, operator decisions, waypoints)."""

    up_axis: str = param("+z", "gravity up direction of the meshes a mission is given")
    frame_id: str = param("map", "frame of the waypoints and proposals")
    # read_only: read when the node starts (its services, the stage caller); the rest is read per mission.
    introspection: bool = param(True, "publish service introspection events (requests and replies) of /perch/crop",
                                read_only=True)
    auto_accept: bool = param(False, "accept every proposal without waiting for an operator (unattended runs); "
                                     "a goal can also ask for it")
    exclusion_radius: float = param(0.3, "a rejected or failed perch excludes perching within this radius", "m",
                                    low=0.0, high=100.0)
    approach_distance: float = param(0.5, "waypoint approach point: this far in front of the perch along its normal", "m",
                                     low=0.0, high=100.0)
    input_up_axis: str = param("auto", "up of a given mesh when the goal names none: auto (estimated; the file format's "
                                       "convention when unsure, glTF +y) or +x, -x, +y, -y, +z, -z, 'x y z'. Outputs "
                                       "stay in the mesh's frame")
    clean_given_mesh: bool = param(True, "run /perch/clean_mesh on a mesh given by file or message before cropping")
    optimise_on_full_mesh: bool = param(True,
                                        "optimise against the uncropped mesh (everything outside the crop still occludes)")
    service_wait: float = param(5.0, "how long to wait for a stage's service to appear before failing", "s", low=0.0,
                                read_only=True)
    stage_timeout: float = param(300.0, "a stage that does not reply within this time fails the mission", "s", low=0.0,
                                 read_only=True)
    gone_grace: float = param(2.0, "a stage whose service vanished for this long during a call fails the mission", "s",
                              low=0.0, read_only=True)
    confirm_timeout: float = param(600.0, "how long a mission waits for operator decisions (0: until cancelled)", "s", low=0.0)
    client_grace: float = param(5.0, "a mission whose client left the graph this long ago is aborted (0: never)", "s", low=0.0)
    crop: CropConfig = field(default_factory=CropConfig)

    def validate(self) -> "OperatorConfig":
        """Raise ValueError naming what is unusable (the up axes)."""
        parse_up_axis(self.up_axis)
        if self.input_up_axis != "auto":
            parse_up_axis(self.input_up_axis)
        return self
