"""The sample index's runs of a box read the samples its positions gather, in the same order."""

import numpy as np

from perch_common.mesh_samples import mesh_samples
from perch_common.scene_generator import generate_scene
from perch_filtering.sampling import SampleIndex, project, read_runs, run_positions
from perch_filtering.voxels import grid_rotation


def _positions_plain(index, corners):
    """Every bucket of the box's bounds in the index's frame, its samples' positions ascending (the
    computation before the runs)."""
    local = project(corners, index.rotation)
    b0 = np.clip(np.floor((local.min(axis=0) - index.lo) / index.bucket).astype(np.int64), 0, index.dims - 1)
    b1 = np.clip(np.floor((local.max(axis=0) - index.lo) / index.bucket).astype(np.int64), 0, index.dims - 1)
    if np.any(local.max(axis=0) < index.lo) or np.any(b0 > b1):
        return np.zeros(0, np.int64)
    keys = np.ravel_multi_index(np.meshgrid(*(np.arange(a, b + 1) for a, b in zip(b0, b1)), indexing="ij"),
                                tuple(index.dims)).ravel()
    return np.flatnonzero(np.isin(index.sorted_key, keys))


def test_runs_of_boxes_read_the_positions_samples():
    scene = generate_scene(3, "two_rooms")
    samples = mesh_samples(scene.mesh, 0.05)
    rng = np.random.default_rng(4)
    lo, hi = scene.mesh.vertices.min(axis=0), scene.mesh.vertices.max(axis=0)
    for bucket in (0.25, 0.5):
        index = SampleIndex(samples, grid_rotation(scene.up), bucket=bucket)
        read = 0
        for _ in range(40):
            a, b = lo - 0.5 + rng.random((2, 3)) * (hi - lo + 1.0)
            corners = np.array([[x, y, z] for x in (a[0], b[0]) for y in (a[1], b[1]) for z in (a[2], b[2])])
            positions = _positions_plain(index, corners)
            np.testing.assert_array_equal(index.positions_near_box(corners), positions)
            start, stop = index.runs_near_box(corners)
            assert np.all(start[1:] > stop[:-1])  # touching runs are joined
            for column in (index.x, index.y, index.z):
                np.testing.assert_array_equal(read_runs(column, start, stop), column[positions])
            where = np.sort(rng.choice(len(positions), min(len(positions), 500), replace=False)) \
                if len(positions) else np.zeros(0, np.int64)
            np.testing.assert_array_equal(run_positions(where, start, stop), positions[where])
            read += len(positions)
        assert read > 10_000
