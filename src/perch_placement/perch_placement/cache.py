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
from perch_common.raycast import RayScene


def mesh_digest(mesh: Mesh) -> str:
    """Content digest of a mesh's vertices and faces."""
    digest = hashlib.blake2b(np.ascontiguousarray(mesh.vertices).tobytes(), digest_size=16)
    digest.update(np.ascontiguousarray(mesh.faces).tobytes())
    return digest.hexdigest()


class PlacementCache:
    """The `size` most recent scenes and candidate sets, least recently used dropped first."""

    def __init__(self, size: int = 2):
        self.size = size
        self._scenes: OrderedDict[str, RayScene] = OrderedDict()
        self._candidates: OrderedDict[str, object] = OrderedDict()

    def scene(self, mesh: Mesh, digest: str | None = None) -> RayScene:
        """The ray-cast scene of a mesh (validated when new; raises MeshError for an unusable mesh)."""
        key = digest or mesh_digest(mesh)
        return self._get(self._scenes, key, lambda: RayScene(validate_mesh(mesh, "environment mesh")))

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
