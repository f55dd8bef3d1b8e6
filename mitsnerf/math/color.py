"""sRGB transfer functions (IEC 61966-2-1), exact piecewise form, on numpy arrays.

With ``x`` a linear value and ``s`` its sRGB encoding::

    s = 12.92 x                      if x <= 0.0031308
    s = 1.055 x^(1/2.4) - 0.055      otherwise

    x = s / 12.92                    if s <= 0.04045
    x = ((s + 0.055) / 1.055)^2.4    otherwise

Values are not clipped: negative inputs take the linear segment, values above
one the power segment. Float inputs keep their dtype; integer inputs become
float64.
"""

from __future__ import annotations

import numpy as np

_LIN_KNEE = 0.0031308
_SRGB_KNEE = 0.04045


def _as_float(x) -> np.ndarray:
    x = np.asarray(x)
    return x if np.issubdtype(x.dtype, np.floating) else x.astype(np.float64)


def linear_to_srgb(x) -> np.ndarray:
    """Encode linear values as sRGB, elementwise, any shape.

    >>> linear_to_srgb([0.0, 0.001, 0.18, 1.0]).round(6).tolist()
    [0.0, 0.01292, 0.461356, 1.0]
    """
    x = _as_float(x)
    power = 1.055 * np.power(np.maximum(x, _LIN_KNEE), 1.0 / 2.4) - 0.055
    return np.where(x <= _LIN_KNEE, 12.92 * x, power).astype(x.dtype, copy=False)


def srgb_to_linear(x) -> np.ndarray:
    """Decode sRGB values to linear, elementwise, any shape; inverse of :func:`linear_to_srgb`.

    >>> srgb_to_linear([0.0, 0.04, 0.5, 1.0]).round(6).tolist()
    [0.0, 0.003096, 0.214041, 1.0]
    >>> float(srgb_to_linear(linear_to_srgb(0.3)).round(12))
    0.3
    """
    x = _as_float(x)
    power = np.power((np.maximum(x, _SRGB_KNEE) + 0.055) / 1.055, 2.4)
    return np.where(x <= _SRGB_KNEE, x / 12.92, power).astype(x.dtype, copy=False)
