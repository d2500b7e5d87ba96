"""The surfaces file is written atomically: a write that fails leaves the previous file whole (issue 22, item 4)."""

import numpy as np
import pytest

from perch_common.surfaces_file import read_surfaces, write_surfaces
from perch_common.types import PlaneFrame, Surface, SurfaceClass


def surface(surface_id: int) -> Surface:
    frame = PlaneFrame.from_normal(np.array([0.0, 0.0, 2.5]), np.array([0.0, 0.0, -1.0]))
    rings = [[np.array([[0, 0], [2, 0], [2, 1], [0, 1.0]])]]
    return Surface(surface_id, frame, 2.0, np.array([1, 2]), SurfaceClass.CEILING, 0.003, np.array([0.5, 0.5]), rings)


@pytest.mark.parametrize("name", ["surfaces.yaml", "surfaces.json"])
def test_a_failed_write_leaves_the_previous_surfaces_file_whole(tmp_path, monkeypatch, name):
    import json

    import yaml

    path = tmp_path / name
    write_surfaces(path, [surface(1), surface(2)], source="first")
    before = path.read_bytes()

    def fail_half_way(document, handle=None, **kwargs):
        if handle is not None:
            handle.write("surfaces:\n- id: 7\n")   # half a document, then the disk fills up
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(yaml, "dump", fail_half_way)
    monkeypatch.setattr(json, "dumps", fail_half_way)
    with pytest.raises(OSError, match="No space left"):
        write_surfaces(path, [surface(7)], source="second")
    assert path.read_bytes() == before
    assert [s.id for s in read_surfaces(path)] == [1, 2]
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]   # no partial file left beside it


def test_surfaces_file_replaced_whole_with_the_umask_mode(tmp_path):
    import os

    path = tmp_path / "surfaces.yaml"
    write_surfaces(path, [surface(1)])
    write_surfaces(path, [surface(3), surface(4)])
    assert [s.id for s in read_surfaces(path)] == [3, 4]
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask
