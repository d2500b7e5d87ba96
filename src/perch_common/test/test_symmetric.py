"""Packed symmetric 3x3 matrices and their closed-form eigenvalues against numpy."""

import numpy as np
import pytest

from perch_common.symmetric import eigenvalues, pack, smallest_eigenvalue, unpack


def random_spd(count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(count, 3, 3))
    return a @ a.transpose(0, 2, 1) + np.eye(3) * rng.random((count, 1, 1))


def test_pack_and_unpack_round_trip():
    m = random_spd(20, 1)
    assert pack(m).shape == (20, 6)
    np.testing.assert_array_equal(unpack(pack(m)), m)
    assert pack(m)[0].tolist() == [m[0, 0, 0], m[0, 1, 1], m[0, 2, 2], m[0, 0, 1], m[0, 0, 2], m[0, 1, 2]]


def test_closed_form_eigenvalues_match_numpy():
    m = random_spd(500, 3)
    np.testing.assert_allclose(eigenvalues(pack(m)), np.linalg.eigvalsh(m), rtol=1e-7, atol=1e-9)
    assert smallest_eigenvalue(pack(m)) == pytest.approx(np.linalg.eigvalsh(m).min(axis=1), rel=1e-7, abs=1e-9)


def test_repeated_eigenvalues_and_multiples_of_the_identity():
    # A single camera's information: a, a, c along and across its ray.
    u = np.array([0.0, 0.6, 0.8])
    m = 5.0 * np.eye(3) + (20.0 - 5.0) * np.outer(u, u)
    np.testing.assert_allclose(eigenvalues(pack(m[None]))[0], [5.0, 5.0, 20.0], rtol=1e-6)
    assert smallest_eigenvalue(np.array([[2.0, 2.0, 2.0, 0, 0, 0]]))[0] == pytest.approx(2.0)
    np.testing.assert_allclose(eigenvalues(np.zeros((1, 6))), [[0.0, 0.0, 0.0]])
