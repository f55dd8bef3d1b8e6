"""render_primitives is the emission-absorption integral of the primitive field, and its replayed gradient is the
derivative of what it renders.

The reference for the values is the shared renderer (:func:`mitsnerf.render.volume.render_rays`) on the kernels'
field with many midpoint samples; for the gradient, central differences of render_primitives itself along random
directions in parameter space (float32: a directional derivative averages out the rounding of one entry).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.primitives import CellLists, Kernels, PrimitiveField, PrimitiveFieldConfig
from mitsnerf.math.box import Box
from mitsnerf.render.primitives import render_primitives
from mitsnerf.render.volume import render_rays

BOX = Box((-0.5, -0.45, -0.4), (0.45, 0.5, 0.5))
BACKGROUND = (0.2, 0.3, 0.4)


def _params(rng, n: int, channels: int, colours: bool):
    return {"mean": rng.uniform(-0.3, 0.3, (n, 3)), "log_scale": np.log(rng.uniform(0.03, 0.1, (n, 3))),
            "rotation": rng.normal(size=(n, 4)), "density": np.log(rng.uniform(1.0, 20.0, (n, channels))),
            "sh": rng.normal(size=(n, 12)) * (1.0 if colours else 0.0)}


def _tensors(p):
    return {key: mi.TensorXf(np.asarray(v, np.float32)) for key, v in p.items()}


def _rays(rng, n: int):
    o = rng.normal(size=(n, 3))
    o = 2.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-0.5, 0.5, (n, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return mi.Array3f(*(o.T.astype(np.float32))), mi.Array3f(*(d.T.astype(np.float32)))


def _render(p, config, o, d, **kw):
    kernels = Kernels(config, _tensors(p) if isinstance(p["mean"], np.ndarray) else p)
    with dr.suspend_grad():
        lists = CellLists.build(kernels, BOX, mi.UInt32)
    return render_primitives(kernels, lists, o, d, box=BOX, background=mi.Array3f(*BACKGROUND), **kw), kernels, lists


def _np(v):
    return np.stack([np.asarray(c, np.float64) for c in v], -1) if dr.depth_v(v) > 1 else np.asarray(v, np.float64)


@pytest.mark.parametrize("channels, colours, kernel", [(1, False, "gaussian"), (3, False, "gaussian"),
                                                      (1, True, "gaussian"), (3, True, "gaussian"),
                                                      (1, False, "ellipsoid"), (3, True, "ellipsoid")])
def test_it_renders_the_kernels_field(channels, colours, kernel):
    rng = np.random.default_rng(channels)
    config = PrimitiveFieldConfig(sh_degree=1, cells=6, density_channels=channels, kernel=kernel)
    o, d = _rays(rng, 96)
    p = _params(rng, 40, channels, colours)
    out, kernels, lists = _render(p, config, o, d, min_transmittance=0.0)
    ref = render_rays(PrimitiveField(kernels, BOX, lists), o, d, 4000, box=BOX, background=mi.Array3f(*BACKGROUND),
                      quadrature="midpoint")
    opacity = _np(out.opacity)
    assert np.count_nonzero(opacity > 0.5) > 10 and np.count_nonzero(opacity < 1e-6) > 5  # dense rays and misses
    # the reference's own error: the midpoint rule across each shell's step of density (~1e-4 here; an ellipsoid's
    # whole density steps there)
    atol = 1e-4 if kernel == "gaussian" else 3e-3
    np.testing.assert_allclose(_np(out.T_final), _np(ref.T_final), atol=atol)
    np.testing.assert_allclose(opacity, _np(ref.opacity), atol=atol)
    if not colours:  # one colour for every kernel: exact
        np.testing.assert_allclose(_np(out.rgb), _np(ref.rgb), atol=atol)
        return
    # each its own: a cell's segment takes their optical-depth-weighted mean colour, an error that shrinks with the
    # cells (on these dense, small kernels of random colours: 0.05 at most with 6 cells per axis)
    coarse = np.abs(_np(out.rgb) - _np(ref.rgb))
    fine, _, _ = _render(p, PrimitiveFieldConfig(sh_degree=1, cells=24, density_channels=channels, kernel=kernel),
                         o, d, min_transmittance=0.0)
    fine = np.abs(_np(fine.rgb) - _np(ref.rgb))
    assert coarse.max() < 0.06 and fine.max() < 0.5 * coarse.max() and fine.mean() < 0.5 * coarse.mean()


def test_rays_stop_below_the_smallest_transmittance():
    rng = np.random.default_rng(7)
    config = PrimitiveFieldConfig(sh_degree=0, cells=4)
    p = {"mean": np.zeros((1, 3)), "log_scale": np.full((1, 3), np.log(0.15)), "rotation": [[0.0, 0, 0, 1]],
         "density": np.full((1, 1), np.log(200.0)), "sh": np.zeros((1, 3))}
    o, d = mi.Array3f(0, 0, -2), mi.Array3f(0, 0, 1)
    full, _, _ = _render(p, config, o, d, min_transmittance=0.0, stats=(s_full := {}))
    stopped, _, _ = _render(p, config, o, d, min_transmittance=1e-3, stats=(s_stop := {}))
    assert _np(full.T_final)[0] < 1e-20 and _np(stopped.T_final)[0] < 1e-3
    np.testing.assert_allclose(_np(stopped.rgb), _np(full.rgb), atol=1e-3)
    assert int(s_stop["visits"][0]) < int(s_full["visits"][0])
    del rng


def _loss(out, n: int, chromatic: bool):
    t = np.random.default_rng(11).uniform(0.0, 1.0, (n, 3)).astype(np.float32)
    target = mi.Array3f(*(mi.Float(t[:, k]) for k in range(3)))
    T = out.T_final if chromatic else mi.Array3f(out.T_final)
    return (dr.mean(dr.square(out.rgb - target), axis=None) + 0.3 * dr.mean(out.opacity, axis=None)
            + 0.05 * dr.mean(out.depth, axis=None) - dr.mean(dr.dot(T, mi.Array3f(0.2, 0.1, -0.3)), axis=None))


@pytest.mark.parametrize("channels, kernel", [(1, "gaussian"), (3, "gaussian"), (1, "ellipsoid")])
def test_the_replayed_gradient_is_the_derivative_of_the_render(channels, kernel):
    rng = np.random.default_rng(20 + channels)
    # a far truncation: the loss is then smooth enough for central differences (at 3, the 1% step of density at
    # each shell puts kinks in it, where the differences converge to the same values only as eps shrinks)
    config = PrimitiveFieldConfig(sh_degree=1, cells=5, density_channels=channels, cutoff=5.0, kernel=kernel)
    o, d = _rays(rng, 64)
    p = _params(rng, 30, channels, True)
    tensors = _tensors(p)
    dr.enable_grad(*tensors.values())
    out, _, _ = _render(tensors, config, o, d)
    dr.backward(_loss(out, 64, channels == 3))
    grads = {k: np.asarray(dr.grad(v).numpy(), np.float64) for k, v in tensors.items()}

    def loss_at(q):
        out, _, _ = _render(q, config, o, d)
        return float(_loss(out, 64, channels == 3)[0])

    # an ellipsoid's geometry: the chord of a ray that grazes it has a derivative without bound, so whole-render
    # differences converge to the gradient only for steps too small for float32; its chord's own derivative is
    # held on single rays (tests/math/test_gaussian.py), the replay is the Gaussians' (above)
    for key in (p if kernel == "gaussian" else ("density", "sh")):
        for trial in range(2):
            direction = rng.normal(size=p[key].shape)
            eps = _step(kernel, key)
            plus, minus = ({**p, key: p[key] + s * eps * direction} for s in (1, -1))
            fd = (loss_at(plus) - loss_at(minus)) / (2 * eps)
            ad = float(np.sum(grads[key] * direction))
            assert ad == pytest.approx(fd, rel=0.01, abs=2e-5), (key, trial)


def _step(kernel: str, key: str) -> float:
    """The central differences' step: well under the kernels' scales (0.03 to 0.1) for the positions."""
    return 5e-4 if key == "mean" else 3e-3


def test_walking_the_rays_in_coherent_order_changes_nothing_but_the_order():
    rng = np.random.default_rng(9)
    config = PrimitiveFieldConfig(sh_degree=1, cells=6)
    o, d = _rays(rng, 200)
    tensors = _tensors(_params(rng, 30, 1, True))
    dr.enable_grad(*tensors.values())
    results = []
    for sort in (True, False):
        out, _, _ = _render(tensors, config, o, d, sort=sort, stats=(stats := {}))
        dr.backward(_loss(out, 200, False))
        results.append(([_np(out.rgb), _np(out.opacity), _np(out.depth), np.asarray(stats["visits"])],
                        [np.asarray(dr.grad(t).numpy()) for t in tensors.values()]))
        for t in tensors.values():
            dr.clear_grad(t)
    (values, grads), (values_unsorted, grads_unsorted) = results
    for a, b in zip(values, values_unsorted):
        np.testing.assert_array_equal(a, b)  # each ray's own arithmetic, whichever packet it is in
    for a, b in zip(grads, grads_unsorted):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5 * np.abs(b).max())  # summed in another order
