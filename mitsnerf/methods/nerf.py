"""``nerf``: positional-encoding MLPs with NeRF's coarse-to-fine (hierarchical) sampling, skipping empty space.

Per ray (Mildenhall et al. 2020, section 5.2)::

    coarse:  N_c stratified samples t_i            -> network_c -> C_c = composite(...)
             w_i = T_i (1 - exp(-sigma_i delta_i))    (the coarse compositing weights)
    fine:    N_f samples from the piecewise-constant pdf of w over the coarse intervals
             [t_i, t_{i+1}] (inverse CDF, mitsnerf.math.sampling.sample_pdf), merged with
             the coarse ones and sorted; deltas from the sorted set
             -> network_f on all N_c + N_f      -> C_f = composite(...)
    loss:    |C_c - C|^2 + |C_f - C|^2            (both networks supervised)

The coarse samples come from :func:`mitsnerf.render.volume.sample_rays` and both passes
composite with :func:`mitsnerf.math.composite.composite`, as every method. ``n_importance = 0``
is the single-pass method: one network, ``n_samples`` stratified samples.

``sampler = "proposal"`` is mip-NeRF 360's and nerfacto's answer to two full networks: a small
density-only *proposal* network on the N_c stratified samples gives weights ``w^p`` whose pdf
places N_f samples, and only those go through the fine network; the proposal is trained by the
interlevel loss (:func:`mitsnerf.math.proposal.interlevel_loss`, weight ``proposal_loss_weight``)
to bound the fine weights from above, not by the photometric loss. The interval before the first
fine sample counts as empty (the proposal says it is).

Empty-space skipping (``use_occupancy``): the occupancy grid that ``ngp`` and ``voxel`` use
(:mod:`mitsnerf.fields.occupancy`, refreshed from the fine network's density every
``occupancy.update_every`` steps) decides which samples reach a network in both passes; the
others count as empty (``sigma = 0``) and are not evaluated. The samples themselves (the
strata, the importance samples) are those of the unskipped method, so a skipped sample changes
a ray only by the weight it would have had, which the grid bounds (``threshold``, dilation, and
the early stop at ``early_stop_T``).

NeRF used 64 + 128 samples and two 8 x 256 networks; the defaults keep the design at a CPU's
size (a 2 x 32 coarse network on 32 samples, the 4 x 64 fine network on 64), and leave out the
view direction (:mod:`mitsnerf.fields.nerf`: on the isotropic media generated here it cost 8 dB).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Literal

import drjit as dr
import drjit.nn as nn
import mitsuba as mi

from mitsnerf.config import check_fields, param
from mitsnerf.fields.nerf import NeRFConfig, NeRFField, NeRFNetwork
from mitsnerf.fields.occupancy import OccupancyConfig, eval_masked
from mitsnerf.math.composite import composite, weights
from mitsnerf.math.proposal import interlevel_loss
from mitsnerf.math.sampling import deltas_from_sorted_t, merge_sorted_t, sample_pdf
from mitsnerf.methods.base import MethodConfig, RenderOutput, SceneInfo, check_shapes, cover_radiance
from mitsnerf.methods.occupancy import OccupancyModel
from mitsnerf.render.volume import background_radiance, sample_rays


@dataclass(frozen=True)
class NeRFMethodConfig(MethodConfig):
    """Configuration of the ``nerf`` method."""

    network: NeRFConfig = param(default_factory=NeRFConfig)
    """The fine network: sizes of the MLP evaluated on coarse + importance samples."""
    coarse_network: NeRFConfig | None = param(default_factory=lambda: NeRFConfig(width=32, depth=2))
    """The coarse network's sizes (it only has to place the fine samples); None: the same as ``network``."""
    n_samples: int = param(32, lo=1, hi=4096)
    """Stratified (coarse) samples per ray N_c."""
    n_importance: int = param(32, lo=0, hi=4096, since=("0.1.0+a7bf3fe", 0))
    """Importance samples per ray N_f drawn from the coarse weights; 0: single pass, one network."""
    sampler: Literal["hierarchical", "proposal"] = param("hierarchical", choices=("hierarchical", "proposal"))
    """How the N_f samples are placed: NeRF's coarse network (``hierarchical``) or a density-only
    proposal network trained by the interlevel loss (``proposal``)."""
    proposal_network: NeRFConfig = param(default_factory=lambda: NeRFConfig(width=32, depth=2, pos_octaves=5, skip=0))
    """The proposal network's trunk (``sampler = "proposal"``; its colour-head sizes are unused)."""
    proposal_loss_weight: float = param(1.0, lo=0.0)
    """Weight of the interlevel loss that trains the proposal network."""
    use_occupancy: bool = param(True, since=("0.1.0+c0fcb9e", False))
    """Skip samples in empty cells of an occupancy grid, and behind an estimated transmittance of
    ``occupancy.early_stop_T`` (the networks are not evaluated there)."""
    occupancy: OccupancyConfig = param(default_factory=OccupancyConfig)
    """The occupancy grid's settings."""
    lr: float = param(5e-3, lo=0.0, lo_open=True)
    """Adam learning rate."""

    def __post_init__(self) -> None:
        check_fields(self)

    @classmethod
    def single_pass(cls, n_samples: int = 64, **kwargs) -> NeRFMethodConfig:
        """One network, ``n_samples`` stratified samples, no fine pass.

        >>> NeRFMethodConfig.single_pass().n_importance
        0
        """
        return cls(n_samples=n_samples, n_importance=0, **kwargs)


def _split_jitter(u, n_rays: int, n_c: int, n_f: int):
    """The trainer's ``u`` (R*(n_c+n_f),) as coarse (R*n_c,) and fine (R*n_f,) jitter (None: None)."""
    if u is None:
        return None, None
    Float = type(u)
    UInt32 = dr.uint32_array_t(Float)
    u_c = dr.gather(Float, u, dr.arange(UInt32, n_rays * n_c))
    u_f = dr.gather(Float, u, dr.arange(UInt32, n_rays * n_c, n_rays * (n_c + n_f))) if n_f else None
    return u_c, u_f


def coarse_edges(t, t_f, n: int):
    """Bin edges ``[t_0, ..., t_{N-1}, t_f]`` per ray (R*(N+1),) of samples ``t`` (R*N,).

    Coarse weight ``w_i`` belongs to the interval ``[t_i, t_{i+1}]`` (``[t_{N-1}, t_f]`` for
    the last), the quadrature's own intervals, so these are the pdf's bins.

    >>> from drjit.llvm import Float
    >>> coarse_edges(Float(0.1, 0.6), Float(1.0), 2)
    [0.1, 0.6, 1]
    """
    Float = type(t)
    UInt32 = dr.uint32_array_t(Float)
    n_rays = dr.width(t) // n
    idx = dr.arange(UInt32, n_rays * (n + 1))
    ray = idx // (n + 1)
    k = idx - ray * (n + 1)
    last = k == n
    tf = dr.gather(Float, t_f, ray) if dr.width(t_f) > 1 else Float(t_f)
    return dr.select(last, tf, dr.gather(Float, dr.detach(t), ray * n + k, ~last))


def _points(o, d, t, n: int):
    """Sample points ``x = o + t d`` and their rays' directions (Array3f (R*n,)) of ``t`` (R*n,), n per ray."""
    ray = dr.arange(dr.uint32_array_t(type(t)), dr.width(t)) // n
    d_s = dr.gather(type(d), d, ray)
    return dr.gather(type(o), o, ray) + t * d_s, d_s


def importance_strata(n_rays: int, n: int, u, Float):
    """Increasing ``u_j = (j + xi_j) / n`` per ray for :func:`sample_pdf` (``xi = 1/2`` without jitter)."""
    UInt32 = dr.uint32_array_t(Float)
    j = dr.arange(UInt32, n_rays * n) % n
    xi = 0.5 if u is None else u
    return (Float(j) + xi) / n


class NeRFNetworks(nn.Module):
    """The method's parameters: the ``fine`` network and, when hierarchical, the ``coarse`` one.

    A ``drjit.nn`` module, so its mapping interface (``fine.trunk.0.weights``, ...,
    ``coarse.head.1.bias``) is what ``drjit.opt`` optimisers take.
    """

    DRJIT_STRUCT = {"fine": NeRFNetwork, "coarse": NeRFNetwork}

    def __init__(self, fine: NeRFNetwork, coarse: NeRFNetwork | None) -> None:
        self.fine = fine
        self.coarse = coarse
        """The hierarchical pass's coarse network, or the proposal network (density only)."""


class NeRFModel(OccupancyModel):
    name = "nerf"
    config_type = NeRFMethodConfig
    description = "positional-encoding MLPs, coarse + importance samples"
    tiny = MappingProxyType({"network": {"width": 8, "depth": 1, "head_width": 8, "features": 4}, "n_samples": 8,
                             "n_importance": 4})

    def __init__(self, config: NeRFMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        self.config = config
        fine = NeRFField.create(cover_radiance(config.network, scene), mi.TensorXf, scene.box, seed)
        super().__init__(fine, config.occupancy if config.use_occupancy else None, scene, seed, config.n_samples)
        self._coarse = None
        if config.n_importance > 0 and config.sampler == "proposal":
            self._coarse = NeRFField.create(config.proposal_network, mi.TensorXf, scene.box, seed + 1, head=False)
        elif config.n_importance > 0:
            coarse = cover_radiance(config.coarse_network or config.network, scene)
            self._coarse = NeRFField.create(coarse, mi.TensorXf, scene.box, seed + 1)
        self.networks = NeRFNetworks(fine.net, self._coarse.net if self._coarse is not None else None)

    @property
    def hierarchical(self) -> bool:
        return self._coarse is not None

    def parameters(self) -> Mapping[str, Any]:
        return self.networks

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """New values of the networks' weights, each of the shape the config builds (the networks never change
        shape)."""
        check_shapes(self.networks, values)
        self.networks.update(values)

    def samples_per_ray(self) -> int:
        """Network evaluations per ray before skipping: N_c (+ N_c + N_f for the fine pass, + N_f with proposals)."""
        c = self.config
        if not self.hierarchical:
            return c.n_samples
        return c.n_samples + c.n_importance + (0 if c.sampler == "proposal" else c.n_samples)

    def jitter_size(self) -> int:
        return self.config.n_samples + (self.config.n_importance if self.hierarchical else 0)

    def _evaluate(self, field, x, d, delta, n: int, density_only: bool = False):
        """``(rgb, sigma)`` of ``field`` at samples ``x`` (N per ray), only where the grid keeps them."""
        fn = (lambda p, w: (mi.Array3f(0.0) + 0.0 * p.x, field.density(p))) if density_only else field
        if self.grid is None:
            return fn(x, d)
        return eval_masked(fn, x, d, self.grid.sample_mask(x, delta, n))

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        if not self.hierarchical:
            return RenderOutput(self.composite(o, d, u, training))
        if self.config.sampler == "proposal":
            return self._render_proposal(o, d, u, training)
        cfg, scene = self.config, self.scene
        n_c, n_f, n_rays = cfg.n_samples, cfg.n_importance, dr.width(o)
        u_c, u_f = _split_jitter(u, n_rays, n_c, n_f)
        bg = background_radiance(scene.background, d)
        Float = type(o.x)

        # Coarse pass: stratified samples through the coarse network (only its weights at evaluation).
        s, _ = sample_rays(o, d, n_c, scene.box, u_c)
        rgb_c, sigma_c = self._evaluate(self._coarse, s.x, s.d, s.delta, n_c, density_only=not training)
        comp_c = composite(sigma_c, s.delta, rgb_c, n_c, background=bg, t=s.t) if training else None
        w_c, _ = weights(dr.detach(sigma_c), s.delta, n_c)

        # Fine pass: importance samples from the coarse weights, merged with the coarse ones.
        _, t_f, _ = scene.box.intersect(o, d)
        t_imp = sample_pdf(coarse_edges(s.t, t_f, n_c), w_c, n_c, n_f, importance_strata(n_rays, n_f, u_f, Float))
        n = n_c + n_f
        t = merge_sorted_t(s.t, n_c, t_imp, n_f)
        delta = deltas_from_sorted_t(t, t_f, n)
        x, d_s = _points(o, d, t, n)
        rgb, sigma = self._evaluate(self.base_field, x, d_s, delta, n)
        comp = composite(sigma, delta, rgb, n, background=bg, t=t)
        return RenderOutput(comp, aux_rgb={"coarse": comp_c.rgb} if training and comp_c is not None else None)

    def _render_proposal(self, o, d, u, training: bool) -> RenderOutput:
        """The proposal network's weights place N_f samples; only those go through the fine network."""
        cfg, scene = self.config, self.scene
        n_p, n_f, n_rays = cfg.n_samples, cfg.n_importance, dr.width(o)
        u_p, u_f = _split_jitter(u, n_rays, n_p, n_f)
        Float = type(o.x)
        s, _ = sample_rays(o, d, n_p, scene.box, u_p)
        _, sigma_p = self._evaluate(self._coarse, s.x, s.d, s.delta, n_p, density_only=True)
        w_p, _ = weights(sigma_p if training else dr.detach(sigma_p), s.delta, n_p)
        _, t_exit, _ = scene.box.intersect(o, d)
        s_edges = coarse_edges(s.t, t_exit, n_p)
        t = sample_pdf(s_edges, w_p, n_p, n_f, importance_strata(n_rays, n_f, u_f, Float))
        delta = deltas_from_sorted_t(t, t_exit, n_f)
        x, d_s = _points(o, d, t, n_f)
        rgb, sigma = self._evaluate(self.base_field, x, d_s, delta, n_f)
        comp = composite(sigma, delta, rgb, n_f, background=background_radiance(scene.background, d), t=t)
        extra = {}
        if training and cfg.proposal_loss_weight > 0:
            w_f, _ = weights(dr.detach(sigma), delta, n_f)  # the interlevel loss trains the proposal only
            loss = interlevel_loss(w_f, coarse_edges(t, t_exit, n_f), n_f, s_edges, w_p, n_p)
            extra["proposal"] = cfg.proposal_loss_weight * loss
        return RenderOutput(comp, extra)


#: The method this module declares (:mod:`mitsnerf.methods` registers it as ``nerf``).
METHOD = NeRFModel
