"""Image and density-grid error metrics on numpy arrays.

Images are float arrays ``(H, W, C)``, or batches ``(V, H, W, C)``. A single
image gives a Python ``float``; a batch gives one value per view, an array of
shape ``(V,)`` (the NeRF papers report the mean of the per-view values, e.g.
``psnr(a, b).mean()``). Arithmetic is in float64 whatever the input dtype.

    mse  = mean (a - b)^2                                  over pixels and channels
    psnr = 10 log10(max_val^2 / mse)                       (inf when a == b)
    ssim = mean over channels and valid pixels of
           (2 mu_a mu_b + C1)(2 s_ab + C2) / ((mu_a^2 + mu_b^2 + C1)(s_a^2 + s_b^2 + C2))

SSIM is the standard one (Wang et al. 2004) as skimage's
``structural_similarity(a, b, channel_axis=-1, gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=max_val)`` and the NeRF papers compute it:
local statistics under an 11x11 Gaussian window (sigma 1.5), ``C1 = (0.01 max_val)^2``,
``C2 = (0.03 max_val)^2``, averaged over the ``(H-10) x (W-10)`` pixels whose
window lies inside the image.
"""

from __future__ import annotations

import numpy as np

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def _pair(a, b) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.ndim not in (3, 4):
        raise ValueError(f"expected an image (H, W, C) or a batch (V, H, W, C), got shape {a.shape}")
    return a, b


def _reduce(values: np.ndarray, batched: bool):
    return values if batched else float(values[0])


def mse(a, b, mask=None):
    """Mean squared error over pixels and channels: ``mean (a - b)^2``.

    ``a``, ``b``: ``(H, W, C)`` or ``(V, H, W, C)``. ``mask``: optional boolean
    ``(H, W)`` (or ``(V, H, W)`` for a batch) selecting the pixels that count;
    every channel of a selected pixel counts. Returns a float, or ``(V,)`` for a batch.

    >>> a = np.zeros((2, 2, 1)); b = np.array([[0.0, 0.1], [0.2, 0.3]])[..., None]
    >>> round(mse(a, b), 6)
    0.035
    >>> round(mse(a, b, mask=np.array([[True, True], [False, False]])), 6)
    0.005
    """
    a, b = _pair(a, b)
    batched = a.ndim == 4
    if not batched:
        a, b = a[None], b[None]
    sq = np.square(a - b)
    if mask is None:
        return _reduce(sq.mean(axis=(1, 2, 3)), batched)
    m = np.asarray(mask)
    if m.dtype != np.bool_:
        raise ValueError(f"mask must be boolean, got dtype {m.dtype}")
    if m.shape == a.shape[1:3]:
        m = np.broadcast_to(m, a.shape[:3])
    elif not (batched and m.shape == a.shape[:3]):
        want = f"{a.shape[1:3]} or {a.shape[:3]}" if batched else f"{a.shape[1:3]}"
        raise ValueError(f"mask shape {m.shape} does not match the images, expected {want}")
    count = m.sum(axis=(1, 2))
    if np.any(count == 0):
        raise ValueError("mask selects no pixels" + (f" in view {int(np.argmin(count))}" if batched else ""))
    total = np.where(m[..., None], sq, 0.0).sum(axis=(1, 2, 3))
    return _reduce(total / (count * a.shape[-1]), batched)


def _psnr_from_mse(err, max_val: float):
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(max_val**2 / np.asarray(err, dtype=np.float64))


def psnr(a, b, mask=None, max_val: float = 1.0):
    """Peak signal-to-noise ratio in dB: ``10 log10(max_val^2 / mse(a, b, mask))``.

    Shapes as :func:`mse`. Identical images give ``inf``. Returns a float, or
    ``(V,)`` for a batch (one PSNR per view; average those for the usual mean PSNR).

    >>> a = np.full((4, 4, 3), 0.5)
    >>> round(psnr(a, a + 0.01), 6)  # mse = 1e-4
    40.0
    >>> psnr(a, a)
    inf
    """
    value = _psnr_from_mse(mse(a, b, mask), max_val)
    return float(value) if value.ndim == 0 else value


def _gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def _filter_valid(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Separable 'valid' correlation of ``x`` (V, H, W, C) with ``w`` along H then W."""
    k = len(w)
    h, wd = x.shape[1] - k + 1, x.shape[2] - k + 1
    y = sum(w[i] * x[:, i : i + h] for i in range(k))
    return sum(w[i] * y[:, :, i : i + wd] for i in range(k))


def ssim(a, b, max_val: float = 1.0):
    """Structural similarity (Gaussian window 11, sigma 1.5, K1 0.01, K2 0.03), mean over channels.

    With ``G*`` the normalised 11x11 Gaussian filter, ``mu_a = G*a``,
    ``s_a^2 = G*(a^2) - mu_a^2``, ``s_ab = G*(ab) - mu_a mu_b`` (population
    covariance) and ``C1 = (0.01 max_val)^2``, ``C2 = (0.03 max_val)^2``, the
    SSIM map is ``(2 mu_a mu_b + C1)(2 s_ab + C2) / ((mu_a^2 + mu_b^2 + C1)(s_a^2 + s_b^2 + C2))``
    on the ``(H-10, W-10)`` valid region; the result is its mean over pixels and
    channels. Images need ``H, W >= 11``. Returns a float, or ``(V,)`` for a batch.

    Constant images ``a = p``, ``b = q`` have zero variances, so SSIM is
    ``(2pq + C1) / (p^2 + q^2 + C1)``:

    >>> round(ssim(np.full((11, 11, 3), 0.5), np.full((11, 11, 3), 0.4)), 6)
    0.975616
    >>> round((2 * 0.5 * 0.4 + 1e-4) / (0.5**2 + 0.4**2 + 1e-4), 6)
    0.975616
    """
    a, b = _pair(a, b)
    batched = a.ndim == 4
    if not batched:
        a, b = a[None], b[None]
    if min(a.shape[1:3]) < SSIM_WINDOW:
        n = SSIM_WINDOW
        raise ValueError(f"SSIM needs images of at least {n}x{n} pixels, got {a.shape[2]}x{a.shape[1]}")
    w = _gaussian_window()
    c1 = (SSIM_K1 * max_val) ** 2
    c2 = (SSIM_K2 * max_val) ** 2
    mu_a, mu_b = _filter_valid(a, w), _filter_valid(b, w)
    var_a = _filter_valid(a * a, w) - mu_a * mu_a
    var_b = _filter_valid(b * b, w) - mu_b * mu_b
    cov = _filter_valid(a * b, w) - mu_a * mu_b
    num = (2.0 * mu_a * mu_b + c1) * (2.0 * cov + c2)
    den = (mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2)
    return _reduce((num / den).mean(axis=(1, 2, 3)), batched)


def density_error(learned, true) -> dict[str, float]:
    """Errors of a learned density grid against the true one (any equal shapes, e.g. ``(R, R, R)``).

    ``rel_l1 = sum|l - t| / sum|t|`` (the cloud-tomography literature's epsilon), ``rel_l2 = ||l - t||_2 / ||t||_2``,
    ``rel_mass = (sum|l| - sum|t|) / sum|t|`` (its delta, signed: > 0 when the learned medium holds more
    extinction than the true one) and ``psnr = 10 log10(max(t)^2 / mean (l - t)^2)`` over all grid cells.

    A grid scaled by ``s`` has ``rel_l1 = rel_l2 = |s - 1|`` and ``rel_mass = s - 1``:

    >>> t = np.array([[0.0, 1.0], [2.0, 4.0]])
    >>> e = density_error(1.5 * t, t)
    >>> round(e["rel_l1"], 6), round(e["rel_l2"], 6), round(e["psnr"], 4)  # mse = 0.25 * 21 / 4
    (0.5, 0.5, 10.8602)
    >>> round(density_error(0.8 * t, t)["rel_mass"], 6)
    -0.2
    """
    s = np.asarray(learned, dtype=np.float64)
    t = np.asarray(true, dtype=np.float64)
    if s.shape != t.shape:
        raise ValueError(f"grids differ in shape: {s.shape} vs {t.shape}")
    if t.size == 0 or not np.any(t):
        raise ValueError("the true grid is empty or all zero: relative errors are undefined")
    diff = s - t
    return {
        "rel_l1": float(np.abs(diff).sum() / np.abs(t).sum()),
        "rel_l2": float(np.linalg.norm(diff.ravel()) / np.linalg.norm(t.ravel())),
        "rel_mass": float((np.abs(s).sum() - np.abs(t).sum()) / np.abs(t).sum()),
        "psnr": float(_psnr_from_mse(np.mean(diff * diff), float(t.max()))),
    }
