"""Each mesh sent once: content ids for meshes, a bounded per-process LRU of received meshes, and
the caller's book of which service already holds which mesh.

Protocol (TriangleMesh.content_id): a mesh message with arrays may name its content id; one with
empty arrays and a content id means "the mesh you already hold under this id". A node that does
not hold it answers success=false with a message starting with MESH_NOT_CACHED; the caller then
sends the arrays again. Every node hosted in one process shares PROCESS_CACHE, so in a
one-process graph the cleaned and cropped meshes reach the next stages by id only; across
processes a stage gets each mesh's arrays once and its id afterwards (re-plans, repeated missions).
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable

import numpy as np

from perch_common.errors import PerchError
from perch_common.mesh import Mesh
from perch_common.threads import one_thread

MESH_NOT_CACHED = "mesh not cached"
DEFAULT_BUDGET_MB = 2048          # per process; PERCH_MESH_CACHE_MB overrides (0 disables the cache)
PREPARE_NICENESS = 15             # the preparing thread's (Linux, per thread): behind the stages


class MeshNotCached(PerchError):
    """A request named a mesh by content id that this node does not hold."""

    def __init__(self, content_id: str, what: str = "mesh"):
        super().__init__(f"{MESH_NOT_CACHED}: {what} {content_id} is not held by this node (it restarted or "
                         "evicted it); send the mesh arrays again")
        self.content_id = content_id


def content_id(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None = None,
               normals: np.ndarray | None = None, viewpoints: np.ndarray | None = None) -> str:
    """A 128-bit hash of the mesh as it travels (float32 vertices, uint32 faces, colours, normals, and
    the float64 viewpoints when it has any: a bare mesh keeps the id it had before they existed).

    SHA-256 cut to 128 bits: hashlib's SHA-256 runs on the CPU's SHA instructions where it has them
    (x86 since 2017-2019, most ARMv8) and hashed a 2.3 M-face building's 42 MB in 44 ms against
    BLAKE2b's 135 ms (two cores of a cloud VM; hashed twice a mission). Ids name arrays for the caches
    only: `perch replay --check` compares the arrays, not the ids, so recordings made with the
    earlier hash still check."""
    digest = hashlib.sha256()
    arrays = [(vertices, np.float32), (faces, np.uint32), (colors, np.uint8), (normals, np.float32)]
    if viewpoints is not None and np.size(viewpoints):
        arrays.append((viewpoints, np.float64))
    for array, dtype in arrays:
        data = np.ascontiguousarray(np.zeros(0) if array is None else array, dtype)
        digest.update(np.int64(data.size).tobytes())
        digest.update(memoryview(data).cast("B"))
    return digest.digest()[:16].hex()


def mesh_content_id(mesh: Mesh) -> str:
    """content_id of a Mesh."""
    return content_id(mesh.vertices, mesh.faces, mesh.vertex_colors, mesh.vertex_normals, mesh.viewpoints)


def _mesh_bytes(mesh: Mesh) -> int:
    """Every array the mesh holds and what stages derive and keep with it (face cross products,
    24 B per face, once face areas or normals were asked for; its ray-cast scene, ~64 B per face)."""
    derived = tuple(mesh._cache.values())   # one C-level copy: another thread may be adding to it
    arrays = (mesh.vertices, mesh.faces, mesh.vertex_colors, mesh.vertex_normals, mesh.viewpoints, *derived)
    return sum(int(getattr(a, "nbytes", 0)) for a in arrays if a is not None)


class MeshCache:
    """Meshes by content id, least recently used dropped first once `budget_bytes` is exceeded.

    `hosts` names the nodes of this process that read requests through this cache, so that a
    caller in the same process can send them a mesh the cache holds by id alone.
    """

    def __init__(self, budget_bytes: int):
        self.budget_bytes = int(budget_bytes)
        self.hosts: set[str] = set()
        # Sizes are measured afresh at every put and get: a held mesh grows when a stage derives
        # per-face data from it (the copies requests get share that data with the held mesh).
        self._items: OrderedDict[str, Mesh] = OrderedDict()
        self._lock = threading.Lock()

    @property
    def used_bytes(self) -> int:
        """Bytes of every array the held meshes hold now."""
        with self._lock:
            return sum(_mesh_bytes(m) for m in self._items.values())

    def _evict(self) -> None:
        """Drop the least recently used meshes until the rest fit the budget (call with the lock held)."""
        used = sum(_mesh_bytes(m) for m in self._items.values())
        while used > self.budget_bytes and self._items:
            _, dropped = self._items.popitem(last=False)
            used -= _mesh_bytes(dropped)

    def put(self, key: str, mesh: Mesh) -> None:
        """Keep `mesh` under `key` (a mesh larger than the whole budget is not kept)."""
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
            elif _mesh_bytes(mesh) <= self.budget_bytes:
                self._items[key] = mesh
            self._evict()

    def get(self, key: str) -> Mesh | None:
        """The mesh under `key` (now the most recently used), or None."""
        with self._lock:
            mesh = self._items.get(key)
            if mesh is None:
                return None
            self._items.move_to_end(key)
            self._evict()   # it may have grown beyond the budget itself: this request still gets it
            return mesh

    def __contains__(self, key: str) -> bool:
        with self._lock:
            return key in self._items

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        """Drop every mesh."""
        with self._lock:
            self._items.clear()


def _budget_from_env() -> int:
    value = os.environ.get("PERCH_MESH_CACHE_MB", "").strip()
    try:
        megabytes = float(value) if value else DEFAULT_BUDGET_MB
    except ValueError:
        raise PerchError(f"PERCH_MESH_CACHE_MB={value!r} is not a number of megabytes") from None
    if megabytes < 0:
        raise PerchError(f"PERCH_MESH_CACHE_MB={value!r} must be >= 0 (0 disables the mesh cache)")
    return int(megabytes * 2**20)


PROCESS_CACHE = MeshCache(_budget_from_env())


# --- preparing held meshes -------------------------------------------------------------------------
# In a one-process graph a stage's reply mesh (the cleaned or cropped scan) is what the next stages
# work on. A node that derives costly data from it (the filter: its ray-cast BVH and surface samples,
# ~2 s on a 2.3 M-face building) registers a preparer; the data is then built on a background thread
# while the stages before it run (segmentation uses one core), and the stage finds it built, or waits
# for the build under way (Mesh.derived). A failed preparation is left for the stage to meet itself.

_preparers: list[Callable[[Mesh], object]] = []
_preparers_lock = threading.Lock()
_prepare_pool: ThreadPoolExecutor | None = None


def add_preparer(preparer: Callable[[Mesh], object]) -> None:
    """Run `preparer(mesh)` on every mesh a stage of this process replies with (until removed)."""
    with _preparers_lock:
        _preparers.append(preparer)


def remove_preparer(preparer: Callable[[Mesh], object]) -> None:
    """Stop preparing meshes with `preparer` (its node is destroyed)."""
    with _preparers_lock:
        if preparer in _preparers:
            _preparers.remove(preparer)


def prepare(mesh: Mesh) -> Future | None:
    """Start the registered preparers on `mesh` on this process's one background thread (in order of
    registration); None when no node registered one."""
    global _prepare_pool
    with _preparers_lock:
        preparers = list(_preparers)
        if not preparers:
            return None
        if _prepare_pool is None:
            _prepare_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="perch-prepare",
                                               initializer=_second_in_line)
    return _prepare_pool.submit(_run_preparers, preparers, mesh)


def _second_in_line() -> None:
    """The preparing thread yields the cores to the stages (Linux niceness is per thread): it runs
    beside segmentation, which uses both; at nice 15 the building's mission took 7.9-8.1 s against
    8.2 s, the preparation moving into segmentation's one-thread spells and the filter's start."""
    try:
        thread = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, thread, max(PREPARE_NICENESS, os.getpriority(os.PRIO_PROCESS, thread)))
    except (AttributeError, OSError):   # no per-thread niceness here: it runs as the stages do
        pass


def _run_preparers(preparers: list[Callable[[Mesh], object]], mesh: Mesh) -> None:
    with one_thread():   # beside the stages: no threads of its own (the surface samples' two halves in turn)
        for preparer in preparers:
            try:
                preparer(mesh)
            except Exception as exc:   # the stage builds it again and reports a real problem itself
                logging.getLogger(__name__).debug("preparing a held mesh failed: %s", exc)


class MeshBook:
    """The caller's knowledge of which service holds which mesh id, to send each mesh once.

    A service holds a mesh it was sent (and answered successfully) or produced in a reply. A
    MESH_NOT_CACHED reply (the node restarted or evicted it) removes that belief.
    """

    def __init__(self) -> None:
        self.held: dict[str, set[str]] = {}
        self._lock = threading.Lock()

    def holds(self, service: str, key: str) -> None:
        """Record that `service` holds mesh `key`."""
        if key:
            with self._lock:
                self.held.setdefault(service, set()).add(key)

    def send_id_only(self, service: str, key: str) -> bool:
        """Whether `service` is known to hold mesh `key`."""
        with self._lock:
            return bool(key) and key in self.held.get(service, ())

    def missed(self, service: str, key: str) -> None:
        """`service` answered MESH_NOT_CACHED for `key`."""
        with self._lock:
            self.held.get(service, set()).discard(key)


def is_mesh_not_cached(message: str) -> bool:
    """Whether a reply message is a MESH_NOT_CACHED error."""
    return message.startswith(MESH_NOT_CACHED) or f": {MESH_NOT_CACHED}:" in message
