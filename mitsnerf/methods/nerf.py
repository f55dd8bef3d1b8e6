"""``nerf``: positional-encoding MLPs with NeRF's coarse-to-fine (hierarchical) sampling.

Per ray (Mildenhall et al. 2020, section 5.2)::

    coarse:  N_c stratified samples t_i            -> network_c -> C_c = composite(...)
             w_i = T_i (1 - exp(-sigma_i delta_i))    (the coarse compositing weights)
    fine:    N_f samples from the piecewise-constant pdf of w over the coarse intervals
             [t_i, t_{i+1}] (inverse CDF, mitsnerf.math.sampling.sample_pdf), merged with
             the coarse ones and sorted; deltas from the sorted set
             -> network_f on all N_c + N_f      -> C_f = composite(...)
    loss:    |C_c - C|^2 + |C_f - C|^2            (both networks supervised)

The coarse samples come from :func:`mitsnerf.render.volume.sample_rays` and both
passes composite with :func:`mitsnerf.math.composite.composite`, as every method.
``n_importance = 0`` is the single-pass method: one network, ``n_samples`` stratified
samples (what ``nerf`` was before the fine pass; ``NeRFMethodConfig.single_pass()``).

| name           | type              | default      | meaning                                          |
|----------------|-------------------|--------------|--------------------------------------------------|
| network        | NeRFConfig        | NeRFConfig() | the fine network (the only one if single-pass)   |
| coarse_network | NeRFConfig / None | 2 x 32       | the coarse network's sizes (None: as network)    |
| n_samples      | int               | 32           | stratified coarse samples per ray N_c            |
| n_importance   | int               | 32           | importance samples per ray N_f (0: single pass)  |
| lr             | float             | 5e-3         | Adam learning rate (2e-2: +1.2 dB at 250 steps, -1.2 dB at 800) |

NeRF used 64 + 128 samples and two 8 x 256 networks; on this CPU the defaults keep the
design at about 1.6 M multiply-adds per ray (a 2 x 32 coarse network on 32 samples, the
4 x 64 fine network on 64): measured 0.74 s per step of 1024 rays on the loaded 2-core
machine, against 1.35 s with the coarse network as large as the fine one and 64
importance samples, and 0.43 s for the former single-pass default (3 x 64, 8 octaves,
64 samples; ``single_pass()`` with those sizes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import drjit as dr
import drjit.nn as nn
import mitsuba as mi

from mitsnerf.fields.nerf import NeRFConfig, NeRFField, NeRFNetwork
from mitsnerf.math.composite import composite, weights
from mitsnerf.math.sampling import deltas_from_sorted_t, merge_sorted_t, sample_pdf
from mitsnerf.methods.base import RayModel, RenderOutput, SceneInfo, cover_radiance
from mitsnerf.render.volume import background_radiance, render_rays, sample_rays


@dataclass(frozen=True)
class NeRFMethodConfig:
    """Configuration of the ``nerf`` method (see the module docstring's table)."""

    network: NeRFConfig = field(default_factory=NeRFConfig)
    """The fine network: sizes of the MLP evaluated on coarse + importance samples."""
    coarse_network: NeRFConfig | None = field(default_factory=lambda: NeRFConfig(width=32, depth=2))
    """The coarse network's sizes (it only has to place the fine samples); None: the same as ``network``."""
    n_samples: int = 32
    """Stratified (coarse) samples per ray N_c."""
    n_importance: int = 32
    """Importance samples per ray N_f drawn from the coarse weights; 0: single pass, one network."""
    lr: float = 5e-3
    """Adam learning rate."""

    def __post_init__(self) -> None:
        if self.n_samples < 1:
            raise ValueError(f"n_samples: must be >= 1, got {self.n_samples}")
        if self.n_importance < 0:
            raise ValueError(f"n_importance: must be >= 0 (0: single pass), got {self.n_importance}")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")

    @classmethod
    def single_pass(cls, n_samples: int = 64, **kwargs) -> "NeRFMethodConfig":
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


class NeRFModel(RayModel):
    name = "nerf"

    def __init__(self, config: NeRFMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        self.config = config
        self.scene = scene
        fine = cover_radiance(config.network, scene)
        self._fine = NeRFField.create(fine, mi.TensorXf, scene.box, seed)
        self._coarse = None
        if config.n_importance > 0:
            coarse = cover_radiance(config.coarse_network or config.network, scene)
            self._coarse = NeRFField.create(coarse, mi.TensorXf, scene.box, seed + 1)
        self.networks = NeRFNetworks(self._fine.net, self._coarse.net if self._coarse is not None else None)

    @property
    def hierarchical(self) -> bool:
        return self._coarse is not None

    def parameters(self) -> Mapping[str, Any]:
        return self.networks

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        self.networks.update(values)

    def samples_per_ray(self) -> int:
        """Network evaluations per ray: N_c (+ N_c + N_f for the fine pass)."""
        c = self.config
        return c.n_samples + (c.n_samples + c.n_importance if self.hierarchical else 0)

    def jitter_size(self) -> int:
        return self.config.n_samples + (self.config.n_importance if self.hierarchical else 0)

    def field(self):
        return self._fine

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        cfg, scene = self.config, self.scene
        if not self.hierarchical:
            return RenderOutput(render_rays(self._fine, o, d, cfg.n_samples, box=scene.box, u=u,
                                            background=scene.background))
        n_c, n_f = cfg.n_samples, cfg.n_importance
        n_rays = dr.width(o)
        u_c, u_f = _split_jitter(u, n_rays, n_c, n_f)
        bg = background_radiance(scene.background, d)
        Float = type(o.x)

        # Coarse pass: stratified samples through the coarse network.
        s, _ = sample_rays(o, d, n_c, scene.box, u_c)
        comp_c = None
        if training:
            rgb_c, sigma_c = self._coarse(s.x, s.d)
            comp_c = composite(sigma_c, s.delta, rgb_c, n_c, background=bg, t=s.t)
        else:
            sigma_c = self._coarse.density(s.x)  # only its weights are needed
        w_c, _ = weights(dr.detach(sigma_c), s.delta, n_c)

        # Fine pass: importance samples from the coarse weights, merged with the coarse ones.
        _, t_f, _ = scene.box.intersect(o, d)
        edges = coarse_edges(s.t, t_f, n_c)
        t_imp = sample_pdf(edges, w_c, n_c, n_f, importance_strata(n_rays, n_f, u_f, Float))
        n = n_c + n_f
        t = merge_sorted_t(s.t, n_c, t_imp, n_f)
        delta = deltas_from_sorted_t(t, t_f, n)
        ray = dr.arange(dr.uint32_array_t(Float), n_rays * n) // n
        d_s = dr.gather(type(d), d, ray)
        x = dr.gather(type(o), o, ray) + t * d_s
        rgb, sigma = self._fine(x, d_s)
        comp = composite(sigma, delta, rgb, n, background=bg, t=t)
        return RenderOutput(comp, aux_rgb={"coarse": comp_c.rgb} if training else None)
