"""The shared conventions: surface classes by the configured angle, filter names, stage services."""

import math

import numpy as np

from perch_common.conventions import (
    CONFIRM_SERVICE,
    FILTER_NAMES,
    NODE_SERVICES,
    STAGE_SERVICES,
    is_wall,
    surface_class,
    surface_classes,
)
from perch_common.types import SurfaceClass

UP = np.array([0.0, 0.0, 1.0])


def tilted(deg_from_horizontal: float, down: bool = False) -> np.ndarray:
    """A unit normal deg_from_horizontal above (or below) the horizon."""
    a = math.radians(deg_from_horizontal)
    return np.array([math.cos(a), 0.0, -math.sin(a) if down else math.sin(a)])


def test_classes_follow_the_configured_angle():
    normals = np.array([tilted(90), tilted(90, down=True), tilted(0), tilted(14), tilted(16), tilted(60), tilted(80)])
    assert surface_classes(normals, UP, 15.0).tolist() == [
        SurfaceClass.FLOOR, SurfaceClass.CEILING, SurfaceClass.WALL, SurfaceClass.WALL,
        SurfaceClass.INTERMEDIATE, SurfaceClass.INTERMEDIATE, SurfaceClass.FLOOR]
    # A wider angle makes the 16 deg surface a wall and the 60 deg one stays between.
    assert surface_classes(normals, UP, 20.0).tolist()[4:] == [SurfaceClass.WALL, SurfaceClass.INTERMEDIATE,
                                                              SurfaceClass.FLOOR]
    assert surface_classes(normals, UP, 5.0).tolist()[3:5] == [SurfaceClass.INTERMEDIATE] * 2
    assert surface_class(tilted(30, down=True), UP, 15.0) == SurfaceClass.INTERMEDIATE
    assert surface_class(tilted(80, down=True), UP, 15.0) == SurfaceClass.CEILING
    # Either way round, in any up direction.
    assert is_wall(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), np.array([0.0, 1.0, 0.0])).all()


def test_filter_names_are_the_removal_fields_in_pipeline_order():
    from pathlib import Path

    msg = Path(__file__).resolve().parents[2] / "perch_interfaces" / "msg" / "FilterRemoval.msg"
    fields = [line.split()[1] for line in msg.read_text().splitlines() if line and not line.startswith("#")]
    assert list(FILTER_NAMES) == [f for f in fields if f not in ("surface_id", "surface_class", "area_total", "area_kept")]
    assert FILTER_NAMES[0] == "orientation" and FILTER_NAMES[-1] == "reachability"


def test_every_stage_service_has_a_node():
    offered = [s for services in NODE_SERVICES.values() for s in services]
    assert sorted(offered) == sorted(list(STAGE_SERVICES.values()) + [CONFIRM_SERVICE])
    assert NODE_SERVICES["perch_placement"] == [STAGE_SERVICES["optimise"]]
