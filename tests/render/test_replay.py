"""render_rays_replay computes render_rays' composite, and its replayed gradient is render_rays' gradient.

The reference is the shared renderer (:func:`mitsnerf.render.volume.render_rays`, or
:func:`mitsnerf.render.skipping.render_rays_skipping` with an occupancy grid) differentiated by Dr.Jit's AD
through its R x N arrays; both see the same rays and jitter. A loss of every output (colour, opacity, depth,
final transmittance) makes every adjoint term of the replay count. The planted bugs at the end change one
module-level helper that the shared loops call, and the comparison must then fail.
"""

from __future__ import annotations

import dataclasses

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsnerf.fields.grid import GridField
from mitsnerf.fields.ngp import NGPConfig, NGPField
from mitsnerf.fields.occupancy import OccupancyConfig, OccupancyGrid
from mitsnerf.fields.voxel import VoxelField, VoxelFieldConfig
from mitsnerf.math.box import UNIT_BOX, Box
from mitsnerf.render import replay
from mitsnerf.render.background import ConstantBackground
from mitsnerf.render.replay import render_rays_replay
from mitsnerf.render.skipping import render_rays_skipping
from mitsnerf.render.volume import render_rays

BOX = Box((-0.7, -0.5, -0.4), (0.6, 0.5, 0.6))  # not the unit box: the replay maps the box it is given


def _rays(n_rays: int, seed: int = 0, spread: float = 0.5):
    """Rays from a sphere of radius 2 towards random points near the centre (some miss the box)."""
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n_rays, 3))
    o = 2.0 * o / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-spread, spread, (n_rays, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (mi.Array3f(*(mi.Float(o[:, k].astype(np.float32)) for k in range(3))),
            mi.Array3f(*(mi.Float(d[:, k].astype(np.float32)) for k in range(3))))


def _jitter(n_rays: int, n: int, seed: int = 1):
    return mi.Float(np.random.default_rng(seed).uniform(0.0, 1.0, n_rays * n).astype(np.float32))


def _loss(out, n_rays: int, seed: int = 2):
    """A loss of all four outputs, with per-ray targets."""
    t = np.random.default_rng(seed).uniform(0.0, 1.0, (n_rays, 3)).astype(np.float32)
    target = mi.Array3f(*(mi.Float(t[:, k]) for k in range(3)))
    return (dr.mean(dr.square(out.rgb - target), axis=None) + 0.3 * dr.mean(out.opacity, axis=None)
            + 0.05 * dr.mean(out.depth, axis=None) - 0.2 * dr.mean(out.T_final, axis=None))


def _run(render, params, n_rays: int):
    """The composite as numpy arrays and the loss's gradient with respect to each of ``params``."""
    out = render()
    dr.backward(_loss(out, n_rays))
    grads = [np.array(dr.grad(p), dtype=np.float64).ravel() for p in params]
    for p in params:
        dr.clear_grad(p)
    values = [np.array(v, dtype=np.float64) for v in (out.rgb, out.opacity, out.depth, out.T_final)]
    return values, grads


def _compare(ref, got, rtol_grad: float = 2e-5):
    """Outputs to float precision; each gradient within ``rtol_grad`` of its largest entry (float round-off
    of sums over many samples, in another order)."""
    for a, b in zip(ref[0], got[0]):
        np.testing.assert_allclose(b, a, rtol=2e-5, atol=2e-6)
    for a, b in zip(ref[1], got[1]):
        scale = np.abs(a).max()
        assert scale > 0.0
        np.testing.assert_allclose(b, a, rtol=0.0, atol=rtol_grad * scale)


def _voxel_grids(res: int = 12, sh_degree: int = 1, seed: int = 3):
    rng = np.random.default_rng(seed)
    c = (np.arange(res) + 0.5) / res - 0.5
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    raw = np.where(x**2 + y**2 + z**2 < 0.12, 1.5, -6.0) + rng.normal(0.0, 0.5, (res,) * 3)
    sigma = mi.TensorXf(raw[..., None].astype(np.float32))
    sh = mi.TensorXf(rng.normal(0.0, 0.4, (res, res, res, 3 * (sh_degree + 1) ** 2)).astype(np.float32))
    dr.enable_grad(sigma, sh)
    return sigma, sh


def voxel_case(n: int = 24, n_rays: int = 96, adjoint: str = "auto"):
    """(reference, replay) on a voxel field: (outputs, gradients of the two grids)."""
    config = VoxelFieldConfig(sh_degree=1, sigma_scale=5.0)
    sigma, sh = _voxel_grids()
    o, d = _rays(n_rays)
    u = _jitter(n_rays, n)
    bg = ConstantBackground((0.2, 0.3, 0.4))

    def ref():
        return render_rays(VoxelField(config, sigma, sh, BOX), o, d, n, box=BOX, u=u, background=bg)

    def rep():
        return render_rays_replay(VoxelField(config, sigma, sh, BOX), o, d, n, box=BOX, u=u, background=bg,
                                  params=[sigma, sh], adjoint=adjoint)

    return _run(ref, [sigma, sh], n_rays), _run(rep, [sigma, sh], n_rays)


@pytest.mark.parametrize("adjoint", ["texture", "generic"])
def test_the_replayed_gradient_is_render_rays_gradient_on_a_voxel_field(adjoint):
    ref, got = voxel_case(adjoint=adjoint)
    _compare(ref, got)


@pytest.mark.parametrize("quadrature", ["seed", "midpoint"])
@pytest.mark.parametrize("n", [1, 7, 32])
def test_forward_and_colour_gradient_on_a_coloured_grid(blob_grid, quadrature, n, each_variant):
    """The ground truth's GridField (sigma_t and colour textures), without jitter, a background per ray."""
    colour = np.random.default_rng(1).uniform(0.1, 1.0, (*blob_grid.shape, 3)).astype(np.float32)
    sigma, col = mi.TensorXf(blob_grid[..., None]), mi.TensorXf(colour)
    dr.enable_grad(sigma, col)
    n_rays = 64
    o, d = _rays(n_rays, seed=4)

    def bg(d):
        return mi.Array3f(0.2 + 0.1 * d.x, 0.3, 0.4 - 0.1 * d.z)

    def render(fn, **kw):
        return lambda: fn(GridField.from_arrays(sigma, BOX, color=col), o, d, n, box=BOX, background=bg,
                          quadrature=quadrature, **kw)

    _compare(_run(render(render_rays), [sigma, col], n_rays), _run(render(render_rays_replay), [sigma, col], n_rays))


def test_with_an_occupancy_grid_it_is_the_skipping_renderer():
    """Samples in empty cells and behind the grid's early stop are skipped alike, the same samples reach the
    field (``stats['kept']`` counts them), and the gradients agree."""
    config = VoxelFieldConfig(sh_degree=1, sigma_scale=5.0)
    sigma, sh = _voxel_grids()
    n, n_rays = 32, 128
    o, d = _rays(n_rays, seed=5)
    u = _jitter(n_rays, n, seed=6)
    grid = OccupancyGrid(OccupancyConfig(resolution=8, early_stop_T=0.05), mi.Float, BOX)
    grid.update(VoxelField(config, sigma, sh, BOX).density, seed=0, step=0)
    assert 0.1 < grid.occupied_fraction() < 0.9
    masks, stats = [], {}

    def ref():
        out, mask = render_rays_skipping(VoxelField(config, sigma, sh, BOX), grid, o, d, n, box=BOX, u=u,
                                         background=0.3)
        masks.append(mask)
        return out

    def rep():
        return render_rays_replay(VoxelField(config, sigma, sh, BOX), o, d, n, box=BOX, u=u, background=0.3,
                                  grid=grid, stats=stats)

    _compare(_run(ref, [sigma, sh], n_rays), _run(rep, [sigma, sh], n_rays))
    kept = int(dr.count(masks[0])[0])
    assert 0 < kept < 0.7 * n_rays * n
    assert int(dr.sum(stats["kept"])[0]) == kept


def _render_float64(sigma, colour, o, d, u, n, background):
    """The loss of :func:`_loss`'s colour term, rgb only, in float64 numpy: the trilinear lookup of a
    ``Texture3f`` (clamped, texel centres at (i + 1/2) / R) and the seed's quadrature, on the unit box."""
    res = sigma.shape[0]
    with np.errstate(divide="ignore"):
        inv = 1.0 / d
    a, b = (-0.5 - o) * inv, (0.5 - o) * inv
    t_n = np.maximum(np.minimum(a, b).max(1), 0.0)
    t_f = np.maximum(a, b).min(1)
    t_f = np.where(t_f > t_n, t_f, t_n)
    i = np.arange(n)
    t = t_n[:, None] + (i + u) / n * (t_f - t_n)[:, None]
    t_next = np.concatenate([t_n[:, None] + (i[1:] + u[:, 1:]) / n * (t_f - t_n)[:, None], t_f[:, None]], 1)
    p = (o[:, None, :] + t[..., None] * d[:, None, :]).reshape(-1, 3) + 0.5
    f = p * res - 0.5
    f0 = np.floor(f).astype(int)
    s, c = 0.0, 0.0
    for corner in range(8):
        bit = [(corner >> k) & 1 for k in range(3)]
        ix = [np.clip(f0[:, k] + bit[k], 0, res - 1) for k in range(3)]
        w = np.prod([(f - f0)[:, k] if bit[k] else 1 - (f - f0)[:, k] for k in range(3)], axis=0)
        s = s + w * sigma[ix[2], ix[1], ix[0]]
        c = c + w[:, None] * colour[ix[2], ix[1], ix[0]]
    tau = s.reshape(-1, n) * (t_next - t)
    T = np.exp(-np.concatenate([np.zeros((len(o), 1)), np.cumsum(tau, 1)], 1))
    rgb = ((T[:, :-1] * -np.expm1(-tau))[..., None] * c.reshape(-1, n, 3)).sum(1) + T[:, -1:] * background
    return rgb


def test_the_gradient_is_as_close_to_float64_finite_differences_as_render_rays():
    """Both renderers against central differences of a float64 renderer (4^3 sigma_t values, 64 rays): the
    replay's running sums in float64 keep nearly opaque rays as accurate as render_rays' suffix sums (both
    8.3e-7 of the largest entry here on LLVM, the replay 2.03e-6 on CUDA, whose gradient sums run in another order;
    with the sums in float32 the replay was 9.1e-6 off, which the bound of 4e-6 still rejects)."""
    rng = np.random.default_rng(9)
    res, n, n_rays = 4, 48, 64
    sigma = rng.uniform(0.0, 25.0, (res,) * 3)
    colour = rng.uniform(0.0, 1.0, (res,) * 3 + (3,))
    o32, d32 = _rays(n_rays, seed=10, spread=0.3)
    o, d = (np.stack([np.array(v[k], np.float64) for k in range(3)], 1) for v in (o32, d32))
    u32 = _jitter(n_rays, n, seed=11)
    u = np.array(u32, np.float64).reshape(n_rays, n)
    target = rng.uniform(0.0, 1.0, (n_rays, 3))

    def loss64(s):
        return np.mean((_render_float64(s, colour, o, d, u, n, 0.5) - target) ** 2)

    fd = np.zeros_like(sigma)
    for idx in np.ndindex(sigma.shape):
        e = np.zeros_like(sigma)
        e[idx] = 1e-6
        fd[idx] = (loss64(sigma + e) - loss64(sigma - e)) / 2e-6
    tensor = mi.TensorXf(sigma[..., None].astype(np.float32))
    dr.enable_grad(tensor)
    tgt = mi.Array3f(*(mi.Float(target[:, k].astype(np.float32)) for k in range(3)))
    errors = {}
    for name, fn in (("render_rays", render_rays), ("replay", render_rays_replay)):
        out = fn(GridField.from_arrays(tensor, UNIT_BOX, color=colour.astype(np.float32)), o32, d32, n,
                 box=UNIT_BOX, u=u32, background=0.5)
        dr.backward(dr.mean(dr.square(out.rgb - tgt), axis=None))
        errors[name] = np.abs(np.array(dr.grad(tensor))[..., 0] - fd).max() / np.abs(fd).max()
        dr.clear_grad(tensor)
    assert errors["render_rays"] < 4e-6
    assert errors["replay"] < 4e-6


def test_the_hash_grid_field_replays_through_its_own_derivative(require_network_path):
    """The ngp field in the loop: hash tables and MLP weights (packed once, outside the loop) get render_rays'
    gradients (the reference evaluates the MLPs on cooperative vectors too: the same arithmetic)."""
    config = NGPConfig(n_levels=3, log2_hashmap_size=10, base_resolution=4, max_resolution=12, hidden=16,
                       geo_features=7, color_hidden=16, sh_degree=1, init_scale=0.5, network_path="coopvec-fp32")
    require_network_path("coopvec-fp32")
    field = NGPField(config, mi.TensorXf, BOX, seed=1)
    params = list(field.params.values())
    dr.enable_grad(params)
    n, n_rays = 16, 48
    o, d = _rays(n_rays, seed=7)
    u = _jitter(n_rays, n, seed=8)
    ref = _run(lambda: render_rays(field, o, d, n, box=BOX, u=u, background=0.5), params, n_rays)
    got = _run(lambda: render_rays_replay(field.loop_field(), o, d, n, box=BOX, u=u, background=0.5,
                                          params=field.params), params, n_rays)
    _compare(ref, got, rtol_grad=1e-4)


def test_the_tensor_path_ngp_field_cannot_be_called_in_the_loop():
    """Where the generic path stops: the tensor MLPs are batch-wide tensors, which a symbolic loop cannot hold
    (hence :meth:`NGPField.loop_field`)."""
    field = NGPField(dataclasses.replace(NGPConfig(), network_path="tensor"), mi.TensorXf, BOX, seed=1)
    o, d = _rays(8)
    with pytest.raises(RuntimeError):
        dr.eval(render_rays_replay(field, o, d, 4, box=BOX, params=field.params).rgb)


def test_a_slab_has_the_closed_form_value_and_derivative():
    """sigma = s on a unit path, c = 1, black background, u = 0: opacity 1 - e^-s, d/ds = e^-s; the colour's
    derivative is the same, the depth's that of sum_i w_i t_i."""
    s = mi.Float(2.0)
    dr.enable_grad(s)
    out = render_rays_replay(lambda x, d: (mi.Array3f(1.0) + 0 * x.x, s + 0 * x.x), mi.Array3f(0, 0, -2),
                             mi.Array3f(0, 0, 1), 8, box=UNIT_BOX, params=s, u=dr.zeros(mi.Float, 8))
    dr.backward(out.rgb.y)
    assert abs(out.opacity[0] - (1 - np.exp(-2.0))) < 1e-6
    assert abs(dr.grad(s)[0] - np.exp(-2.0)) < 1e-6


def test_rays_that_miss_see_the_background_and_give_no_gradient():
    sigma, sh = _voxel_grids()
    field = VoxelField(VoxelFieldConfig(), sigma, sh, BOX)
    o, d = mi.Array3f(3.0, 3.0, 3.0), mi.Array3f(0.0, 0.0, 1.0)
    stats: dict = {}
    out = render_rays_replay(field, o, d, 16, box=BOX, background=0.25, stats=stats)
    dr.backward(out.rgb.x)
    assert out.rgb.x[0] == 0.25 and out.T_final[0] == 1.0 and stats["kept"][0] == 0
    assert not np.any(np.array(dr.grad(sigma))) and not np.any(np.array(dr.grad(sh)))


def test_arguments_are_checked():
    o, d = _rays(2)
    field = VoxelField(VoxelFieldConfig(), *_voxel_grids(), BOX)
    with pytest.raises(ValueError, match="n_samples"):
        render_rays_replay(field, o, d, 0, box=BOX)
    with pytest.raises(ValueError, match="u has 3 entries"):
        render_rays_replay(field, o, d, 4, box=BOX, u=dr.zeros(mi.Float, 3))
    with pytest.raises(ValueError, match="adjoint"):
        render_rays_replay(field, o, d, 4, box=BOX, adjoint="fast")


# -- planted bugs: each one a module-level helper of the shared loops, changed; the comparison must fail --

def _transmittance_after_the_sample(tau, sigma, delta):
    return dr.exp(-(tau + sigma * delta)), replay.one_minus_exp_neg(sigma * delta)


def _last_interval_not_to_the_exit(i, n, t_n, t_f, u, u_next, quadrature):
    t, delta = PLAIN_INTERVAL(i, n, t_n, t_f, u, u_next, quadrature)
    return t, dr.select(i + 1 == n, (t_f - t_n) / n, delta)


def _radiance_behind_forgotten(delta, T_next, s, after):
    return delta * T_next * s


PLAIN_INTERVAL = replay.sample_interval
MUTATIONS = {
    "transmittance": _transmittance_after_the_sample,  # T_i taken after the sample (forward and gradient)
    "sample_interval": _last_interval_not_to_the_exit,  # the last delta h, not t_f - t_{N-1}
    "sigma_adjoint": _radiance_behind_forgotten,  # dL/dsigma without -delta A_after (the gradient alone)
}


@pytest.mark.parametrize("helper", sorted(MUTATIONS))
def test_a_planted_bug_in_the_replay_fails_the_comparison(monkeypatch, helper):
    monkeypatch.setattr(replay, helper, MUTATIONS[helper])
    ref, got = voxel_case(n=12, n_rays=48)
    with pytest.raises(AssertionError):
        _compare(ref, got)


# -- the methods that adopt it: the flag changes the renderer, not the training --

def _blob_views(blob_grid, n_views: int = 4, size: int = 10):
    from mitsnerf.math.camera import Camera, look_at
    from mitsnerf.math.rays import camera_rays
    from mitsnerf.methods.base import SceneInfo
    from mitsnerf.train import PixelData

    rng = np.random.default_rng(0)
    cams = [Camera.from_fov(look_at(2.0 * v / np.linalg.norm(v)), size, size, 40.0)
            for v in rng.normal(size=(n_views, 3))]
    bg = ConstantBackground((0.05, 0.1, 0.3))
    rays = camera_rays(mi.Array3f, cams)
    with dr.suspend_grad():
        comp = render_rays(GridField.from_arrays(blob_grid, UNIT_BOX, color=(1.0, 0.9, 0.1)), rays.o, rays.d, 64,
                           background=bg, box=UNIT_BOX)
    images = np.stack([np.asarray(c) for c in comp.rgb], -1).reshape(n_views, size, size, 3)
    return PixelData.from_views(images, cams), SceneInfo(UNIT_BOX, bg, float(images.max()))


# measured on LLVM: voxel 2.5e-7, ngp 6e-8, ngp fp16 2.2e-5 (fp16 products on CUDA's tensor cores not yet measured)
@pytest.mark.parametrize("method, rtol", [("voxel", 1e-4), ("ngp", 1e-4), ("ngp fp16", 1e-3)])
def test_training_with_the_replay_follows_the_shared_renderer(blob_grid, method, rtol, require_network_path):
    """The same seed and batches, through occupancy updates and (voxel) an upsampling: the losses agree to
    float round-off, and the grid lets the same share of samples through. ngp's replayed march runs its MLPs
    on fp32 cooperative vectors (not on CUDA) unless the network is on fp16 ones: ``ngp fp16`` is the replay
    that CUDA runs."""
    from mitsnerf.methods import get_method
    from mitsnerf.train import TrainConfig, train

    if method == "ngp":
        require_network_path("coopvec-fp32")
    method, fp16 = method.split()[0], method.endswith("fp16")

    data, info = _blob_views(blob_grid)
    entry = get_method(method)
    settings = {"n_samples": 24, "occupancy": {"resolution": 8, "update_every": 4}}
    if method == "voxel":
        settings.update({"resolution": 8, "initial_resolution": 4, "upsample_steps": [9]})
    else:
        settings["network"] = {"n_levels": 2, "log2_hashmap_size": 10, "base_resolution": 8, "max_resolution": 16,
                               "hidden": 8, "color_hidden": 8, **({"network_path": "coopvec-fp16"} if fp16 else {})}
    losses, active = {}, {}
    for flag in (False, True):
        from mitsnerf.config import from_dict

        model = entry.model_type(from_dict(entry.config_type, {**settings, "replay": flag}), info, 0)
        result, _ = train(model, data, TrainConfig(steps=16, batch_rays=64, log_every=1), model.config.lr,
                          progress=False)
        losses[flag] = [h["loss"] for h in result.history]
        active[flag] = model.active_fraction
    np.testing.assert_allclose(losses[True], losses[False], rtol=rtol)
    assert active[True] == active[False] < 1.0
    assert losses[True][-1] < losses[True][0]
