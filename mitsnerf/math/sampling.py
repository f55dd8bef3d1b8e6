"""Sample positions along rays.

Layout used throughout mitsnerf: ``R`` rays with ``N`` samples each are stored as
flat Dr.Jit arrays of size ``R * N``, ray-major (the samples of ray ``r`` are the
block ``[r * N, (r + 1) * N)``). Per-ray quantities are arrays of size ``R``.

Every function here is type-generic: it works on whatever Dr.Jit array type it is
given (LLVM or CUDA, with or without AD).
"""

from __future__ import annotations

import drjit as dr

QUADRATURES = ("seed", "midpoint")
"""The quadrature rules of :func:`stratified_t`: the seed's rule (the default) and the exact midpoint rule."""


def stratified_t(t_n, t_f, n: int, u=None, quadrature: str = "seed"):
    """Stratified sample distances and their interval lengths along each ray.

    Formula (0-based ``i = 0 .. N-1``; docs/conventions.md writes it 1-based), ``h = (t_f - t_n) / N``::

        t_i     = t_n + (i + u_i) h,     u_i ~ U[0, 1)

    so each ``t_i`` lies in its own stratum ``[t_n + i h, t_n + (i+1) h)``. The interval
    each sample stands for depends on ``quadrature``:

    - ``"seed"`` (the default; the project's specification)::

          delta_i = t_{i+1} - t_i,   delta_{N-1} = t_f - t_{N-1}

      The deltas of a ray sum to ``t_f - t_0``: each sample stands for ``[t_i, t_{i+1})``.
      With midpoints (``u = 0.5``) the optical depth is ``h sum_{i<N-1} sigma(t_i) +
      (h/2) sigma(t_{N-1})``, the midpoint rule minus half an interval at the exit: its error
      is ``-(h/2) sigma_t(t_f) + O(h^2)``, first order in ``1/N`` where the medium is dense at
      the exit, second order where it vanishes there. ``u = 0`` everywhere gives the left
      Riemann sum from ``t_n``, exact for constant ``sigma``.
    - ``"midpoint"``: ``delta_i = h``; each sample stands for its whole stratum (the
      intervals ``(t_start, t_end)`` partition ``[t_n, t_f]``). With ``u = 0.5`` this is the
      midpoint rule, error ``O(h^2)`` whatever the density at the ends; with jittered ``u``
      the optical depth is a stratified Monte Carlo estimate, unbiased.

    Args:
        t_n, t_f: per-ray entry and exit distances, Float of shape (R,).
        n: samples per ray, N >= 1.
        u: jitter in [0, 1), Float of shape (R*N,); None places every sample at its
           stratum's midpoint (u = 0.5), the deterministic choice for evaluation.
        quadrature: ``"seed"`` or ``"midpoint"`` (see above).

    Returns:
        (t, delta), each Float of shape (R*N,).

    Example (one ray from 0 to 1, N = 4, midpoints)::

        >>> from drjit.llvm import Float
        >>> t, delta = stratified_t(Float(0.0), Float(1.0), 4)
        >>> t
        [0.125, 0.375, 0.625, 0.875]
        >>> delta
        [0.25, 0.25, 0.25, 0.125]
        >>> stratified_t(Float(0.0), Float(1.0), 4, quadrature="midpoint")[1]
        [0.25, 0.25, 0.25, 0.25]
    """
    if n < 1:
        raise ValueError(f"stratified_t: n must be >= 1, got {n}")
    if quadrature not in QUADRATURES:
        raise ValueError(f"stratified_t: quadrature must be one of {', '.join(QUADRATURES)}, got {quadrature!r}")
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
    if quadrature == "midpoint":
        delta = span / n + dr.zeros(Float, n_rays * n)
    else:
        t_next = dr.select(i + 1 == n, tf, tn + (fi + 1 + u_next) / n * span)
        delta = t_next - t
    return t, delta


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


def count_before(values, n_values: int, queries, n_queries: int, inclusive: bool):
    """Per ray, how many of the ray's (sorted) ``values`` lie before each of its ``queries``.

    Counts ``v < q`` (``inclusive=False``) or ``v <= q`` (``inclusive=True``) by a
    binary search in the ray's block of ``n_values`` entries; UInt32 of shape (R*n_queries,).
    """
    Float = type(queries)
    UInt32 = dr.uint32_array_t(Float)
    n_rays = dr.width(queries) // n_queries
    ray = dr.arange(UInt32, n_rays * n_queries) // n_queries
    base = ray * n_values
    count = dr.zeros(UInt32, n_rays * n_queries)
    step = 1
    while step * 2 <= n_values:
        step *= 2
    while step >= 1:
        cand = count + step
        ok = cand <= n_values
        v = dr.gather(Float, values, base + dr.minimum(cand, n_values) - 1, ok)
        before = (v <= queries) if inclusive else (v < queries)
        count = dr.select(ok & before, cand, count)
        step //= 2
    return count


def merge_sorted_t(t_a, n_a: int, t_b, n_b: int):
    """Merge two per-ray sorted sets of distances into one sorted set of ``n_a + n_b`` per ray.

    Each ray's block of ``t_a`` (``n_a`` entries) and of ``t_b`` (``n_b`` entries)
    must be increasing, as :func:`stratified_t` and :func:`sample_pdf` (with
    increasing ``u``) give them. Entry ``i`` of ray ``r``'s ``t_a`` lands at position
    ``i + #{j : t_b[j] < t_a[i]}`` of the ray's merged block, entry ``j`` of ``t_b`` at
    ``j + #{i : t_a[i] <= t_b[j]}`` (ties put ``t_a`` first), so the result is the
    per-ray ``sort(concat(t_a, t_b))`` without a sort: two binary searches and a scatter.
    The output is detached (sample positions carry no gradient, as in NeRF).

    Args:
        t_a: Float (R*n_a,), e.g. the coarse samples.
        t_b: Float (R*n_b,), e.g. the importance samples.

    Returns:
        Float (R*(n_a+n_b),), increasing within each ray.

    Example (one ray)::

        >>> from drjit.llvm import Float
        >>> merge_sorted_t(Float(0.1, 0.5, 0.9), 3, Float(0.4, 0.5), 2)
        [0.1, 0.4, 0.5, 0.5, 0.9]
    """
    Float = type(t_a)
    UInt32 = dr.uint32_array_t(Float)
    t_a, t_b = dr.detach(t_a), dr.detach(t_b)
    n = n_a + n_b
    n_rays = dr.width(t_a) // n_a
    if dr.width(t_b) != n_rays * n_b:
        raise ValueError(f"merge_sorted_t: t_b has {dr.width(t_b)} entries, expected R*n_b = {n_rays * n_b}")
    out = dr.zeros(Float, n_rays * n)
    idx_a = dr.arange(UInt32, n_rays * n_a)
    ray_a = idx_a // n_a
    pos_a = ray_a * n + (idx_a - ray_a * n_a) + count_before(t_b, n_b, t_a, n_a, inclusive=False)
    idx_b = dr.arange(UInt32, n_rays * n_b)
    ray_b = idx_b // n_b
    pos_b = ray_b * n + (idx_b - ray_b * n_b) + count_before(t_a, n_a, t_b, n_b, inclusive=True)
    dr.scatter(out, t_a, pos_a)
    dr.scatter(out, t_b, pos_b)
    return out


def deltas_from_sorted_t(t, t_f, n: int):
    """Interval lengths of per-ray sorted sample distances, the last interval ending at ``t_f``.

    The same quadrature convention as :func:`stratified_t`::

        delta_i = t_{i+1} - t_i  (i < N-1),     delta_{N-1} = t_f - t_{N-1}

    so a ray's deltas sum to ``t_f - t_0``.

    Args:
        t: Float (R*N,), increasing within each ray.
        t_f: Float (R,), exit distance of each ray.
        n: samples per ray N.

    Returns:
        Float (R*N,).

    Example (one ray leaving at 1)::

        >>> from drjit.llvm import Float
        >>> deltas_from_sorted_t(Float(0.1, 0.4, 0.5, 0.9), Float(1.0), 4)
        [0.3, 0.1, 0.4, 0.1]
    """
    Float = type(t)
    UInt32 = dr.uint32_array_t(Float)
    idx = dr.arange(UInt32, dr.width(t))
    ray = idx // n
    last = idx - ray * n + 1 == n
    t_next = dr.gather(Float, t, idx + 1, ~last)
    tf = dr.gather(Float, t_f, ray) if dr.width(t_f) > 1 else Float(t_f)
    return dr.select(last, tf, t_next) - t
