"""Synthetic meshes with known planes, for tests and demos (box rooms with doors and noise)."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh

WALL_RGB = (224, 220, 208)
DOOR_RGB = (96, 64, 40)
FLOOR_RGB = (150, 111, 74)


def grid_rect(origin, u_vec, v_vec, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle split into nu x nv quads (2 triangles each), wound so normals are u x v."""
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
    vertices = (np.asarray(origin, float) + i.reshape(-1, 1) / nu * np.asarray(u_vec, float)
                + j.reshape(-1, 1) / nv * np.asarray(v_vec, float))
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return vertices, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def weld(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate meshes, merging coincident vertices; returns vertices, faces, part of each face."""
    offset, vertices, faces, part = 0, [], [], []
    for k, (v, f) in enumerate(parts):
        vertices.append(v)
        faces.append(f + offset)
        part.append(np.full(len(f), k))
        offset += len(v)
    v = np.concatenate(vertices)
    _, first, inverse = np.unique(np.round(v, 6), axis=0, return_index=True, return_inverse=True)
    return v[first], inverse.reshape(-1)[np.concatenate(faces)], np.concatenate(part)


def box_room(size=(4.0, 3.0, 2.5), cell: float = 0.1, noise: float = 0.0, seed: int = 0,
             door: bool = False) -> tuple[Mesh, np.ndarray]:
    """A closed box room (normals inward), coloured; returns (mesh, ground-truth plane per face).

    Planes: 0 floor, 1 ceiling, 2..5 walls (x=0, x=X, y=0, y=Y); with door=True a 0.9 x 2.0 m
    door-coloured rectangle on wall 2 (flush) is plane 6.
    """
    x, y, z = size
    n = lambda length: max(1, int(round(length / cell)))  # noqa: E731
    rects = [
        ((0, 0, 0), (x, 0, 0), (0, y, 0)),   # floor, normal +z
        ((0, 0, z), (0, y, 0), (x, 0, 0)),   # ceiling, normal -z
        ((0, 0, 0), (0, y, 0), (0, 0, z)),   # wall x=0, normal +x
        ((x, 0, 0), (0, 0, z), (0, y, 0)),   # wall x=X, normal -x
        ((0, 0, 0), (0, 0, z), (x, 0, 0)),   # wall y=0, normal +y
        ((0, y, 0), (x, 0, 0), (0, 0, z)),   # wall y=Y, normal -y
    ]
    parts = [grid_rect(o, u, v, n(np.linalg.norm(u)), n(np.linalg.norm(v))) for o, u, v in rects]
    vertices, faces, plane = weld(parts)
    colors = np.tile(np.array(WALL_RGB, np.uint8), (len(vertices), 1))
    colors[faces[plane == 0].ravel()] = FLOOR_RGB
    if door:
        centre = vertices[faces].mean(axis=1)
        inside = (plane == 2) & (centre[:, 1] > 1.0) & (centre[:, 1] < 1.9) & (centre[:, 2] < 2.0)
        plane[inside] = 6
        colors[faces[inside].ravel()] = DOOR_RGB
    if noise > 0:
        vertices = vertices + np.random.default_rng(seed).normal(0.0, noise, vertices.shape)
    return Mesh(vertices, faces, colors), plane
