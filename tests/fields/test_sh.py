import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.sh import num_coefficients, sh_basis


def _fibonacci_sphere(n):
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1).astype(np.float32)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_basis_is_orthonormal_on_the_sphere(degree):
    d = _fibonacci_sphere(20000)
    Y = np.stack([np.asarray(v, np.float64) * np.ones(len(d)) for v in sh_basis(mi.Array3f(d[:, 0], d[:, 1], d[:, 2]), degree)])
    assert Y.shape[0] == num_coefficients(degree)
    gram = 4 * np.pi * (Y @ Y.T) / len(d)
    np.testing.assert_allclose(gram, np.eye(len(Y)), atol=2e-3)


def test_band_one_is_linear_in_the_direction():
    d = mi.Array3f([0.6, 0.0], [0.8, 0.0], [0.0, -1.0])
    Y = [np.asarray(v) for v in sh_basis(d, 1)]
    c1 = np.sqrt(3 / (4 * np.pi))
    np.testing.assert_allclose(np.stack(Y[1:]), c1 * np.array([[-0.8, 0.0], [0.0, -1.0], [-0.6, 0.0]]), atol=1e-6)


def test_degree_is_checked():
    with pytest.raises(ValueError):
        sh_basis(mi.Array3f(0, 0, 1), 4)
