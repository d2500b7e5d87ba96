"""Batched ray casting against a mesh, shared by the stages: Embree through embreex.

embreex loads in 6 ms; Open3D, whose RaycastingScene wraps the same Embree, takes ~0.45 s to import
(its whole library and Python bindings), paid by every `perch plan` although a mesh mission needs
nothing else of it. Both give the same hits (checked on 400k rays on the apartment scan). Open3D
is still loaded for closest-point queries (reports, benchmarks and test checkers), on first use.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from perch_common.mesh import Mesh
from perch_common.threads import work_threads

MISS = -1
SCENE_BYTES_PER_FACE = 64   # Embree's BVH: ~62 B a face (measured on 957k faces)
PARALLEL_RAYS = 1 << 16     # rays from which a batch is split over the ray threads (embreex releases the GIL)
SEGMENT_BLOCK = 1 << 14     # segments prepared at once by occluded: ~200 KB a temporary, in cache


@dataclass
class RayHits:
    """First hits: distance along the (unit) ray, face index (MISS when none), unit face normal."""

    distance: np.ndarray
    face: np.ndarray
    normal: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(N,) whether each ray hit a face."""
        return self.face != MISS


def _float32_rows(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(values, np.float32).reshape(-1, 3))


_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def _blocks(part: slice, size: int) -> list[slice]:
    """`part` (a slice with explicit bounds) cut into consecutive slices of at most `size`."""
    return [slice(first, min(first + size, part.stop)) for first in range(part.start, part.stop, size)] or [part]


def _in_parallel(count: int, work) -> list:
    """work(slice) over `count` rays: in chunks on the ray threads when the batch is large."""
    threads = work_threads()  # as many as OpenMP gets (Open3D's ray caster used that many)
    if count < PARALLEL_RAYS or threads == 1:
        return [work(slice(0, count))]
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="perch-rays")
    bounds = np.linspace(0, count, threads + 1).astype(int)
    return list(_pool.map(work, [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]))


class RayScene:
    """A mesh prepared for ray queries; build once, query many times (from any thread)."""

    def __init__(self, mesh: Mesh):
        from embreex import mesh_construction, rtcore_scene

        self.mesh = mesh
        self._scene = None
        self._closest = None   # Open3D's scene, for closest_points only
        self._closest_lock = threading.Lock()   # built once, by a preparing thread or the first query
        self._normals = None   # unit face normals, for cast
        if mesh.num_faces:
            # robust: watertight edge and vertex hits (a ray through a shared edge hits one face).
            self._scene = rtcore_scene.EmbreeScene(robust=True)
            self._geometry = mesh_construction.TriangleMesh(self._scene, _float32_rows(mesh.vertices),
                                                            np.ascontiguousarray(mesh.faces, np.int32))
            # The BVH is built by the first query: build it here, before threads share the scene.
            self._scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), query="OCCLUDED")

    @property
    def nbytes(self) -> int:
        """Estimated memory of the scene (what a mesh cache counts when the scene is kept with its mesh)."""
        return SCENE_BYTES_PER_FACE * self.mesh.num_faces

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> RayHits:
        """First hit of each ray; directions need not be unit (distance is in their units). The
        normal is the hit face's right-hand-winding normal."""
        origins, directions = _float32_rows(origins), _float32_rows(directions)
        face = np.full(len(origins), MISS, np.int64)
        distance = np.full(len(origins), np.inf)
        normal = np.zeros((len(origins), 3))
        if len(origins) and self._scene is not None:
            parts = _in_parallel(len(origins), lambda part: self._scene.run(origins[part], directions[part], output=1))
            face = np.concatenate([p["primID"] for p in parts]).astype(np.int64)
            face[face < 0] = MISS
            hit = face != MISS
            distance[hit] = np.concatenate([p["tfar"] for p in parts])[hit]
            if self._normals is None:
                self._normals = self.mesh.face_normals()
            normal[hit] = self._normals[face[hit]]
        return RayHits(distance, face, normal)

    def first_hit_distance(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """`cast(...).distance` (inf where a ray misses) from Embree's distance query: no faces,
        normals or hit records (a third of cast's CPU on a large batch)."""
        origins, directions = _float32_rows(origins), _float32_rows(directions)
        if len(origins) == 0 or self._scene is None:
            return np.full(len(origins), np.inf)
        return np.concatenate(_in_parallel(len(origins), lambda part: self._scene.run(
            origins[part], directions[part], dists=np.full(part.stop - part.start, np.inf, np.float32),
            query="DISTANCE"))).astype(np.float64)

    def any_hit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Whether each ray hits the mesh at all (`cast(...).hit`): Embree's occlusion query stops at
        the first face it meets instead of finding the nearest, ~4x less CPU where only hit or miss counts."""
        origins, directions = _float32_rows(origins), _float32_rows(directions)
        if len(origins) == 0 or self._scene is None:
            return np.zeros(len(origins), bool)
        return np.concatenate(_in_parallel(len(origins), lambda part: self._scene.run(
            origins[part], directions[part], query="OCCLUDED") == 0))

    def occluded(self, origins: np.ndarray, targets: np.ndarray, epsilon: float = 1e-3) -> np.ndarray:
        """True where the segment origin->target hits the mesh, ignoring `epsilon` metres at both ends."""
        origins, targets = _float32_rows(origins), _float32_rows(targets)
        if len(origins) == 0 or self._scene is None:
            return np.zeros(len(origins), bool)

        def segments(part: slice) -> np.ndarray:
            return np.concatenate([self._occluded_block(origins[block], targets[block], epsilon)
                                   for block in _blocks(part, SEGMENT_BLOCK)])

        return np.concatenate(_in_parallel(len(origins), segments))

    def _occluded_block(self, origins: np.ndarray, targets: np.ndarray, epsilon: float) -> np.ndarray:
        """`occluded` of one cache-sized block of float32 segments (temporaries stay in cache and
        are not page-faulted in anew for millions of rays)."""
        # Float32 throughout (what Embree takes): the preparation must not cost more than the rays.
        delta = targets - origins
        length = np.sqrt(np.einsum("ij,ij->i", delta, delta))
        usable = length > 2 * epsilon
        skip = np.divide(epsilon, length, out=np.zeros_like(length), where=usable)
        starts = delta * skip[:, None]   # epsilon along the segment
        starts += origins
        delta *= (1 - 2 * skip)[:, None]  # to epsilon before its end
        blocked = self._scene.run(starts, delta, dists=np.ones(len(starts), np.float32), query="OCCLUDED") == 0
        return blocked & usable

    def closest_point_scene(self):
        """(open3d, its RaycastingScene of the mesh) for closest_points: imported and built on first
        use (0.3-0.45 s, mostly the import), which a stage can pay ahead of its request (prepare_mesh)."""
        with self._closest_lock:
            if self._closest is None:
                from perch_common.open3d_loader import open3d

                o3d = open3d()
                scene = o3d.t.geometry.RaycastingScene()
                scene.add_triangles(o3d.core.Tensor(_float32_rows(self.mesh.vertices)),
                                    o3d.core.Tensor(np.ascontiguousarray(self.mesh.faces, np.uint32)))
                self._closest = o3d, scene
            return self._closest

    def closest_points(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest mesh point, its face and the distance for each query point (Open3D, loaded and
        built on first use; the stages ask `perch_common.proximity.clear_of_mesh` instead)."""
        pts = _float32_rows(points)
        if len(pts) == 0:
            return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0)
        o3d, scene = self.closest_point_scene()
        ans = scene.compute_closest_points(o3d.core.Tensor(pts))
        closest = ans["points"].numpy().astype(np.float64)
        face = ans["primitive_ids"].numpy().astype(np.int64)
        return closest, face, np.linalg.norm(closest - pts, axis=1)


def sphere_directions(count: int) -> np.ndarray:
    """(count, 3) unit directions spread evenly over the sphere (Fibonacci lattice, deterministic)."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def ray_scene(mesh: Mesh) -> RayScene:
    """The mesh's ray-cast scene, built once and kept with the mesh (`Mesh.derived`): in a one-process
    graph the filter, placement and the operator's views query one BVH (60 ms on 100k faces, 1.5 s
    on a building) instead of building three."""
    return mesh.derived("ray_scene", lambda: RayScene(mesh))
