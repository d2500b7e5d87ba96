"""What the placement stage keeps between requests: ray-cast scenes and unconstrained candidate sets.

Re-optimising after a rejection (same mesh, regions and target, one more exclusion zone) then costs
no BVH build and no candidate ray casting. Entries are keyed by content, never by object identity,
and the cache belongs to its owner (the node, a benchmark run), not to the module.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from typing import Callable

import numpy as np

from perch_common.mesh import Mesh, validate_mesh
from perch_common.raycast import RayScene, ray_scene


def mesh_digest(mesh: Mesh) -> str:
    """Content digest of a mesh's vertices and faces."""
    digest = hashlib.blake2b(np.ascontiguousarray(mesh.vertices).tobytes(), digest_size=16)
    digest.update(np.ascontiguousarray(mesh.faces).tobytes())
    return digest.hexdigest()


class PlacementCache:
    """The `size` most recent scenes and candidate sets, least recently used dropped first.

    The scenes kept hold at most `max_scene_faces` faces together (None: no limit): a ray-cast scene
    costs about 150 bytes per face, so a very large mesh's scene is built for its request and freed
    after it instead of staying in the node (a re-plan on it builds it again).
    """

    def __init__(self, size: int = 2, max_scene_faces: int | None = None):
        self.size = size
        self.max_scene_faces = max_scene_faces
        self._scenes: OrderedDict[str, RayScene] = OrderedDict()
        self._scene_faces: dict[str, int] = {}
        self._candidates: OrderedDict[str, object] = OrderedDict()

    @property
    def scene_faces(self) -> int:
        """Faces of the scenes now kept."""
        return sum(self._scene_faces.values())

    def scene(self, mesh: Mesh, digest: str | None = None) -> RayScene:
        """The ray-cast scene of a mesh (validated when new; raises MeshError for an unusable mesh)."""
        key = digest or mesh_digest(mesh)
        if key in self._scenes:
            self._scenes.move_to_end(key)
            return self._scenes[key]
        scene = ray_scene(validate_mesh(mesh, "environment mesh"))   # the mesh's own, when a stage built it
        if self.max_scene_faces is not None and mesh.num_faces > self.max_scene_faces:
            return scene   # too large to keep
        self._scenes[key], self._scene_faces[key] = scene, mesh.num_faces
        while len(self._scenes) > self.size or (self.max_scene_faces is not None
                                                and self.scene_faces > self.max_scene_faces):
            dropped, _ = self._scenes.popitem(last=False)
            del self._scene_faces[dropped]
        return scene

    def candidates(self, key: str, build: Callable[[], object]):
        """The candidate set stored under `key`, built by `build()` when absent."""
        return self._get(self._candidates, key, build)

    def _get(self, store: OrderedDict, key: str, build: Callable[[], object]):
        if key not in store:
            store[key] = build()
            while len(store) > self.size:
                store.popitem(last=False)
        store.move_to_end(key)
        return store[key]
