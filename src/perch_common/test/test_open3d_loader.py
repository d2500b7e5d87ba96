"""Open3D through perch_common.open3d_loader: usable at once, its Plotly viewer deferred yet working."""

import subprocess
import sys

SCRIPT = """
import sys
import numpy as np
from perch_common.open3d_loader import open3d
from perch_common.raycast import RayScene
from perch_common.mesh import Mesh

o3d = open3d()
assert "dash" not in sys.modules and "plotly" not in sys.modules, "the web viewer was imported"
# ray casting (what Perch uses) works: a unit square at z = 0 seen from above
mesh = Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
hits = RayScene(mesh).cast(np.array([[0.5, 0.5, 2.0]]), np.array([[0.0, 0.0, -1.0]]))
assert abs(hits.distance[0] - 2.0) < 1e-6, hits.distance
# the deferred functions keep their names and load the real module on their first call
draw = o3d.visualization.get_plotly_fig
assert draw.__name__ == "get_plotly_fig"
cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).random((20, 3))))
figure = draw([cloud])
assert type(figure).__name__ == "Figure" and "dash" in sys.modules
assert o3d.visualization.draw_plotly.__module__ == "open3d.visualization.draw_plotly"
print("ok")
"""


def test_open3d_loads_without_its_web_viewer_and_the_viewer_still_works():
    # A fresh interpreter: the test process may have imported Open3D the ordinary way already.
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]
