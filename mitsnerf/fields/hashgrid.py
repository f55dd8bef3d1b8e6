"""The multiresolution hash grid's settings, declared once: :class:`HashGridConfig`, the base of every config whose
field encodes positions with instant-ngp's hash grid (the ``ngp`` field's :class:`~mitsnerf.fields.ngp.NGPConfig`,
``scatter``'s :class:`~mitsnerf.fields.media.HashMediumConfig`), and the encoding built from them.

A config inherits the fields, so their keys stay at its top level (``--set network.n_levels=4`` for ngp,
``--set hash.n_levels=4`` for scatter), with one range, default and meaning each::

    p     = box.to_unit(x)                                              in [0, 1]^3
    h(p)  = [trilinear lookup of level l's table at p * N_l]_{l < L}    (drjit.nn.HashGridEncoding)
            N_l = N_min * b^l,  b = (N_max / N_min)^(1 / (L - 1)); a level is a dense grid
            while it fits in 2^T entries, a hash table of 2^T entries beyond

The defaults (3 levels from 16 to 24) are measured in :mod:`mitsnerf.fields.ngp`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mitsnerf.config import check_fields, param


@dataclass(frozen=True)
class HashGridConfig:
    """Sizes of a multiresolution hash grid (the module's docstring)."""

    n_levels: int = param(3, lo=1, hi=32)
    """Resolution levels L."""
    features_per_level: int = param(2, choices=(2, 4, 8))
    """Features F per level (drjit's hash grid takes an even F dividing the table size)."""
    log2_hashmap_size: int = param(15, lo=8, hi=24)
    """T: at most 2^T entries per level."""
    base_resolution: int = param(16, lo=1)
    """N_min, the coarsest level's resolution."""
    max_resolution: int = param(24, lo=1)
    """N_max, the finest level's resolution (>= ``base_resolution``)."""
    init_scale: float = param(1e-4, lo=0.0, lo_open=True)
    """Hash-table entries start uniform in ``+-init_scale``."""

    def __post_init__(self) -> None:
        check_fields(self)
        if self.max_resolution < self.base_resolution:
            raise ValueError(
                f"max_resolution: must be >= base_resolution ({self.base_resolution}), got {self.max_resolution}"
            )

    @property
    def per_level_scale(self) -> float:
        """``b = (N_max / N_min)^(1 / (L - 1))`` (1 for a single level).

        >>> HashGridConfig(n_levels=3, base_resolution=16, max_resolution=64).per_level_scale
        2.0
        """
        if self.n_levels == 1:
            return 1.0
        return math.exp(math.log(self.max_resolution / self.base_resolution) / (self.n_levels - 1))

    @property
    def n_features(self) -> int:
        """Features the encoding gives per point: ``L F``."""
        return self.n_levels * self.features_per_level

    def encoding(self, TensorXf, rng):
        """The :class:`drjit.nn.HashGridEncoding` of 3D unit positions with these settings (its table drawn
        from ``rng``)."""
        import drjit as dr
        import drjit.nn as nn

        return nn.HashGridEncoding(dr.leaf_t(TensorXf), 3, n_levels=self.n_levels,
                                   n_features_per_level=self.features_per_level,
                                   hashmap_size=2**self.log2_hashmap_size, base_resolution=self.base_resolution,
                                   per_level_scale=self.per_level_scale, init_scale=self.init_scale, rng=rng)
