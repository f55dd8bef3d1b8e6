"""The network-training problem that ``throughput_mlp.py`` and its JAX peer ``jax_mlp_peer.py`` both solve.

numpy only, so that the peer's Python (a throw-away venv with JAX, without mitsnerf) imports it too.
The network: x in [0, 1)^3 -> [sin(2^k pi x_c), cos(2^k pi x_c)] for k < ``FREQS`` (60 features) ->
``DIMS`` (two ReLU hidden layers of 64) -> 4 outputs, trained on mean squared error with Adam
(``LR``, betas 0.9 / 0.999, eps 1e-8).
"""

from __future__ import annotations

import numpy as np

FREQS = 10
DIMS = (3 * 2 * FREQS, 64, 64, 4)
LR = 1e-3
BETAS = (0.9, 0.999)
EPS = 1e-8


def batch(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` inputs uniform in [0, 1)^3 (numpy ``default_rng(seed)``) and their 4 smooth targets, float32.

    The targets: ``s_0 s_1``, ``s_1 s_2``, ``s_2 s_0`` with ``s_c = sin(2 pi x_c)``, and the bump
    ``exp(-8 |x - 1/2|^2)``.

    >>> x, t = batch(5)
    >>> x.shape, t.shape, x.dtype, t.dtype
    ((5, 3), (5, 4), dtype('float32'), dtype('float32'))
    """
    rng = np.random.default_rng(seed)
    x = rng.random((n, 3), dtype=np.float32)
    s = np.sin(2.0 * np.pi * x)
    bump = np.exp(-8.0 * np.sum((x - 0.5) ** 2, axis=1))
    return x, np.column_stack([s[:, 0] * s[:, 1], s[:, 1] * s[:, 2], s[:, 2] * s[:, 0], bump]).astype(np.float32)


def flops_per_point() -> int:
    """Matrix-product FLOPs of one training step per point: ``2 sum(d_i d_{i+1})`` forward, twice that backward."""
    return 3 * 2 * sum(a * b for a, b in zip(DIMS[:-1], DIMS[1:]))
