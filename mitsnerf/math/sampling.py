"""Sample positions along rays.

Layout used throughout mitsnerf: ``R`` rays with ``N`` samples each are stored as
flat Dr.Jit arrays of size ``R * N``, ray-major (the samples of ray ``r`` are the
block ``[r * N, (r + 1) * N)``). Per-ray quantities are arrays of size ``R``.

Every function here is type-generic: it works on whatever Dr.Jit array type it is
given (LLVM or CUDA, with or without AD).
"""

from __future__ import annotations

import drjit as dr


def stratified_t(t_n, t_f, n: int, u=None):
    """Stratified sample distances and their interval lengths along each ray.

    Formula (0-based ``i = 0 .. N-1``; DEVELOPERS.md writes it 1-based)::

        t_i     = t_n + (i + u_i) / N * (t_f - t_n),     u_i ~ U[0, 1)
        delta_i = t_{i+1} - t_i,   delta_{N-1} = t_f - t_{N-1}

    so each ``t_i`` lies in its own stratum ``[t_n + i/N (t_f - t_n), t_n + (i+1)/N (t_f - t_n))``
    and the deltas of a ray sum to ``t_f - t_0``: the quadrature covers ``[t_0, t_f]``,
    leaving out ``[t_n, t_0)`` (expected length ``(t_f - t_n) / 2N``), so its error in
    optical depth is first order in ``1/N``. ``u_0 = 0`` makes it start at ``t_n``.

    Args:
        t_n, t_f: per-ray entry and exit distances, Float of shape (R,).
        n: samples per ray, N >= 1.
        u: jitter in [0, 1), Float of shape (R*N,); None places every sample at its
           stratum's midpoint (u = 0.5), the deterministic choice for evaluation.

    Returns:
        (t, delta), each Float of shape (R*N,).

    Example (one ray from 0 to 1, N = 4, midpoints)::

        >>> from drjit.llvm import Float
        >>> t, delta = stratified_t(Float(0.0), Float(1.0), 4)
        >>> t
        [0.125, 0.375, 0.625, 0.875]
        >>> delta
        [0.25, 0.25, 0.25, 0.125]
    """
    if n < 1:
        raise ValueError(f"stratified_t: n must be >= 1, got {n}")
    Float = type(t_n)
    UInt32 = dr.uint32_array_t(Float)
    n_rays = max(dr.width(t_n), dr.width(t_f))
    idx = dr.arange(UInt32, n_rays * n)
    ray = idx // n
    i = idx - ray * n
    tn = dr.gather(Float, t_n, ray) if dr.width(t_n) > 1 else Float(t_n)
    tf = dr.gather(Float, t_f, ray) if dr.width(t_f) > 1 else Float(t_f)
    span = tf - tn
    if u is None:
        u = dr.full(Float, 0.5, n_rays * n)
        u_next = u
    else:
        if dr.width(u) != n_rays * n:
            raise ValueError(
                f"stratified_t: u has {dr.width(u)} entries, expected R*N = {n_rays * n}"
            )
        u_next = dr.gather(Float, u, idx + 1, i + 1 < n)
    fi = Float(i)
    t = tn + (fi + u) / n * span
    last = i + 1 == n
    t_next = dr.select(last, tf, tn + (fi + 1 + u_next) / n * span)
    return t, t_next - t


def sample_pdf(bins, weights, n_bins: int, n: int, u=None, eps: float = 1e-5):
    """Inverse-CDF (hierarchical) sampling of new distances from per-ray weights.

    Each ray has ``n_bins`` bins with edges ``bins`` (``n_bins + 1`` per ray) and
    non-negative ``weights`` (``n_bins`` per ray). A piecewise-constant pdf
    ``p_k = (w_k + eps) / sum_j (w_j + eps)`` is sampled ``n`` times by inverting its
    CDF, linearly inside each bin (as NeRF's ``sample_pdf``)::

        CDF_0 = 0,  CDF_k = sum_{j<k} p_j;   t = e_k + (u - CDF_k) / p_k * (e_{k+1} - e_k)
        where k is the bin with CDF_k <= u < CDF_{k+1}

    Args:
        bins: Float (R*(n_bins+1),), increasing bin edges per ray.
        weights: Float (R*n_bins,), e.g. the coarse pass's compositing weights.
        n_bins: bins per ray.
        n: samples to draw per ray.
        u: Float (R*n,) in [0, 1); None takes the stratum midpoints (i + 0.5)/n.

    Returns:
        Float (R*n,): sample distances, increasing within each ray when u is.

    Example (all weight in the second of two bins [0, 1], [1, 2])::

        >>> from drjit.llvm import Float
        >>> sample_pdf(Float(0, 1, 2), Float(0, 1), 2, 2, eps=0.0)
        [1.25, 1.75]
    """
    Float = type(weights)
    UInt32 = dr.uint32_array_t(Float)
    n_rays = dr.width(weights) // n_bins
    w = dr.detach(weights) + eps
    cdf_excl = dr.block_prefix_sum(w, n_bins, exclusive=True)
    total = dr.block_sum(w, n_bins)
    idx = dr.arange(UInt32, n_rays * n)
    ray = idx // n
    j = idx - ray * n
    if u is None:
        u = (Float(j) + 0.5) / n
    target = u * dr.gather(Float, total, ray)

    # Binary search for the last bin k of the ray with cdf_excl[k] <= target.
    base = ray * n_bins
    lo = dr.zeros(UInt32, n_rays * n)
    size = n_bins
    step = 1
    while step < size:
        step *= 2
    step //= 2
    while step >= 1:
        cand = lo + step
        ok = cand < n_bins
        value = dr.gather(Float, cdf_excl, base + dr.minimum(cand, n_bins - 1), ok)
        lo = dr.select(ok & (value <= target), cand, lo)
        step //= 2
    c_k = dr.gather(Float, cdf_excl, base + lo)
    w_k = dr.gather(Float, w, base + lo)
    e_base = ray * (n_bins + 1) + lo
    e0 = dr.gather(Float, dr.detach(bins), e_base)
    e1 = dr.gather(Float, dr.detach(bins), e_base + 1)
    frac = dr.clip((target - c_k) / dr.maximum(w_k, 1e-20), 0.0, 1.0)
    return e0 + frac * (e1 - e0)
