"""Only ceilings and floors are judged in any yaw: a wall's window keeps gravity's axes."""

import numpy as np
from filtering_accuracy import filter_input_surfaces

from perch_common.scene_generator import generate_scene
from perch_common.types import SurfaceClass
from perch_filtering import core


def test_walls_keep_the_upright_window_ceilings_turn_it(monkeypatch):
    scene = generate_scene(1, "room")
    config = core.FilterConfig(processes=1)  # the judged surfaces are seen in this process
    judged, support = [], core._support

    def recording(w, *args, **kwargs):
        judged.append((w.surface.surface_class, w.window))
        return support(w, *args, **kwargs)

    monkeypatch.setattr(core, "_support", recording)
    core.filter_surfaces(scene.mesh, filter_input_surfaces(scene), scene.target, scene.up, config)
    walls = [window for kind, window in judged if kind == SurfaceClass.WALL]
    ceilings = [window for kind, window in judged if kind == SurfaceClass.CEILING]
    assert walls and ceilings
    # No window kernel on a wall: support is not turned and the observed-space prism keeps its axes.
    assert all(window is None for window in walls)
    assert all(np.array_equal(window, core.any_yaw_window(config)) for window in ceilings)
