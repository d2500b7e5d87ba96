"""Per-cluster sufficient statistics: merging two clusters is a sum, their plane fit a 3x3 eigenproblem.

Columns of the (n, K) table: area, integral of x (3), integral of x x^T (6: xx yy zz xy xz yz),
area-weighted face normal sum (3, for the winding majority), area-weighted CIELAB sum (3) and
area-weighted RGB sum (3) and the area-weighted sum of n n^T over face normals (6: how the faces
face a direction, whatever their winding). Integrals are exact for triangles, so a cluster's covariance is that of
its surface, not of its vertices.
"""

from __future__ import annotations

import numpy as np

from perch_common import symmetric

AREA = 0
FIRST = slice(1, 4)
SECOND = slice(4, 10)
NORMAL = slice(10, 13)
LAB = slice(13, 16)
RGB = slice(16, 19)
NORMAL2 = slice(19, 25)
STEP1_COLUMNS = 16  # area, moments, winding and colour: what step 1 reads
_TINY_AREA = 1e-18
_PLANE_DEFINED = 1e-9  # second/largest spread ratio (squared widths) below which a cluster is a line


def face_table(triangles: np.ndarray, areas: np.ndarray, unit_normals: np.ndarray,
               lab: np.ndarray | None, rgb: np.ndarray | None) -> np.ndarray:
    """Statistics of each face as its own cluster; triangles (F,3,3) already centred."""
    zero = np.zeros(len(areas))
    x, y, z = (np.ascontiguousarray(triangles[:, :, k]) for k in range(3))  # (F,3) corner coordinates
    coords = (x, y, z)
    sums = [c.sum(axis=1) for c in coords]
    columns = [areas] + [areas * s / 3.0 for s in sums]
    # Exact second moment of a triangle: A/12 (sum_i v_i v_i^T + s s^T).
    for i, j in symmetric.SYM6:
        vv = np.einsum("ij,ij->i", coords[i], coords[j])
        columns.append(areas / 12.0 * (vv + sums[i] * sums[j]))
    n = [np.ascontiguousarray(unit_normals[:, k]) for k in range(3)]
    columns += [areas * n[k] for k in range(3)]
    columns += [areas * lab[:, k] for k in range(3)] if lab is not None else [zero] * 3
    columns += [areas * rgb[:, k] for k in range(3)] if rgb is not None else [zero] * 3
    columns += [areas * n[i] * n[j] for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))]
    return np.stack(columns, axis=1)


def aggregate(table: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """Statistics of the clusters `labels` (values 0..count-1) groups the rows into."""
    from scipy.sparse import csr_matrix

    # A 0/1 membership matrix times the table: one pass, faster than a bincount per column.
    members = csr_matrix((np.ones(len(labels)), (labels, np.arange(len(labels)))), shape=(count, len(labels)))
    return np.asarray(members @ table)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (n,3) arrays (np.cross is several times slower on these)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Euclidean distance of (n,3) arrays."""
    d = a - b
    return np.sqrt(np.einsum("ij,ij->i", d, d))


def covariance(area: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(n,6) area-weighted covariance (xx yy zz xy xz yz) from summed moments."""
    a = np.maximum(area, _TINY_AREA)[:, None]
    mean = first / a
    cov = second / a
    cov[:, 0:3] -= mean * mean
    cov[:, 3] -= mean[:, 0] * mean[:, 1]
    cov[:, 4] -= mean[:, 0] * mean[:, 2]
    cov[:, 5] -= mean[:, 1] * mean[:, 2]
    return cov


def smallest_eigenvalue(cov: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of each (n,6) covariance, at least 0 (covariances are positive semi-definite)."""
    return np.maximum(symmetric.smallest_eigenvalue(cov), 0.0)


def plane_energy(table: np.ndarray) -> np.ndarray:
    """Mean squared distance of each cluster's surface to its best-fit plane (m^2)."""
    cov = covariance(table[:, AREA], table[:, FIRST], table[:, SECOND])
    return smallest_eigenvalue(cov)


def merged_energy(table: np.ndarray, u: np.ndarray, v: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
    """plane_energy of the union of clusters u[k] and v[k], in chunks to bound memory."""
    out = np.empty(len(u))
    cols = slice(0, 10)  # area, first and second moments only
    for start in range(0, len(u), chunk):
        end = start + chunk
        merged = table[u[start:end], cols] + table[v[start:end], cols]
        cov = covariance(merged[:, 0], merged[:, 1:4], merged[:, 4:10])
        out[start:end] = smallest_eigenvalue(cov)
    return out


def plane_normals(table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (n,3) and unit best-fit plane normals (n,3), oriented by the faces' winding.

    The smallest eigenvector of each covariance C, in closed form: the rows of C - lambda I span
    a plane whose normal is it, so take the longest cross product of two rows. Much cheaper than
    a batched eigh when called every round.
    """
    area = np.maximum(table[:, AREA], _TINY_AREA)
    centroid = table[:, FIRST] / area[:, None]
    c = covariance(table[:, AREA], table[:, FIRST], table[:, SECOND])
    lam = smallest_eigenvalue(c)
    r0 = np.stack([c[:, 0] - lam, c[:, 3], c[:, 4]], -1)
    r1 = np.stack([c[:, 3], c[:, 1] - lam, c[:, 5]], -1)
    r2 = np.stack([c[:, 4], c[:, 5], c[:, 2] - lam], -1)
    candidates = np.stack([cross(r0, r1), cross(r0, r2), cross(r1, r2)], axis=1)
    lengths = np.linalg.norm(candidates, axis=2)
    best = np.argmax(lengths, axis=1)
    rows = np.arange(len(c))
    length = lengths[rows, best]
    fallback = winding_normals(table)  # degenerate (collinear or empty) clusters
    # Rows of a plane's C - lambda I cross to ~ lambda2 * lambda3; a line's (a leftover sliver) to
    # float residue, whose direction differs in every frame: such a cluster takes its winding.
    trace = c[:, 0] + c[:, 1] + c[:, 2]
    defined = length > np.maximum(_PLANE_DEFINED * trace * trace, 1e-30)
    normals = np.where(defined[:, None], candidates[rows, best] / np.maximum(length, 1e-300)[:, None],
                       fallback)
    flip = np.einsum("ij,ij->i", normals, table[:, NORMAL]) < 0
    normals[flip] *= -1.0
    return centroid, normals


def pca_frames(table: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centroids (n,3), eigenvalues ascending (n,3) and eigenvectors (n,3,3) as columns."""
    area = np.maximum(table[:, AREA], _TINY_AREA)
    centroid = table[:, FIRST] / area[:, None]
    c = covariance(table[:, AREA], table[:, FIRST], table[:, SECOND])
    mats = np.stack([np.stack([c[:, 0], c[:, 3], c[:, 4]], -1),
                     np.stack([c[:, 3], c[:, 1], c[:, 5]], -1),
                     np.stack([c[:, 4], c[:, 5], c[:, 2]], -1)], axis=1)
    values, vectors = np.linalg.eigh(mats)
    return centroid, np.maximum(values, 0.0), vectors


def oriented_normals(table: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """PCA normals (smallest eigenvector) flipped to agree with the faces' winding majority."""
    normals = vectors[:, :, 0].copy()
    flip = np.einsum("ij,ij->i", normals, table[:, NORMAL]) < 0
    normals[flip] *= -1.0
    return normals


def quadratic_form(sym: np.ndarray, n: np.ndarray) -> np.ndarray:
    """n^T S n for (k,6) symmetric matrices (xx yy zz xy xz yz) and (k,3) vectors."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    return (sym[:, 0] * x * x + sym[:, 1] * y * y + sym[:, 2] * z * z
            + 2.0 * (sym[:, 3] * x * y + sym[:, 4] * x * z + sym[:, 5] * y * z))


def fit_to_plane(table: np.ndarray, normal: np.ndarray, point: np.ndarray) -> np.ndarray:
    """Mean squared distance of each cluster's surface to the plane (normal[k], point[k]):
    n^T Cov n + (n . (mean - point))^2, from the cluster's moments alone."""
    area = np.maximum(table[:, AREA], _TINY_AREA)
    cov = covariance(table[:, AREA], table[:, FIRST], table[:, SECOND])
    mean = table[:, FIRST] / area[:, None]
    return np.maximum(quadratic_form(cov, normal), 0.0) + np.einsum("ij,ij->i", mean - point, normal) ** 2


def mean_lab(table: np.ndarray) -> np.ndarray:
    """(n,3) area-weighted mean CIELAB colour."""
    return table[:, LAB] / np.maximum(table[:, AREA], _TINY_AREA)[:, None]


# A summed winding shorter than this share of the area has cancelled (a double-sided face: both
# windings over the same triangle). Its float residue (~1e-16 of the area) points anywhere, and in
# another orientation somewhere else: tested against 0, a 0.02 deg turn changed what step 1 merged.
_CANCELLED_WINDING = 1e-9


def winding_normals(table: np.ndarray) -> np.ndarray:
    """Unit area-weighted mean face normal (cheap orientation estimate; zero if it cancels)."""
    n = table[:, NORMAL]
    length = np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
    cancelled = _CANCELLED_WINDING * np.maximum(table[:, AREA], _TINY_AREA)[:, None]
    return np.divide(n, length, out=np.zeros_like(n), where=length > cancelled)
