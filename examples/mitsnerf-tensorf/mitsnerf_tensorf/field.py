"""TensoRF's vector-matrix (VM) field (Chen et al. 2022, "TensoRF: Tensorial Radiance Fields"), in Dr.Jit.

A feature of the unit point ``p = box.to_unit(x)`` is a sum of R vector-matrix products, one triple of
them per component, each pairing a plane with the line orthogonal to it::

    f(p) = sum_r  M^XY_r(p_x, p_y) v^Z_r(p_z) + M^XZ_r(p_x, p_z) v^Y_r(p_y) + M^YZ_r(p_y, p_z) v^X_r(p_x)

with the planes ``M`` (R_g, R_g, C) and the lines ``v`` (R_g, C) looked up bilinearly / linearly
(``Texture2f`` / ``Texture1f``, ``use_accel=False``, clamped borders, texel centres at ``(i + 1/2) / R_g``,
the grid convention of :mod:`mitsnerf.fields.grid`); gradients reach the tensors through the lookups.

- density: one VM of ``density_components`` components per plane, summed into a scalar, then
  ``sigma = distance_scale * softplus(f + density_shift)`` (TensoRF's ``feature2density``; ``exp``:
  ``distance_scale * exp(f + density_shift)``, clamped);
- appearance: a second VM of ``app_components`` per plane, its ``3 C_a`` products concatenated (not summed),
  times the basis matrix ``B`` (3 C_a, basis_width), then decoded to a colour: ``sh`` (TensoRF's SH render
  mode, ``B f`` read as SH coefficients: ``c_max * sigmoid(sum_k k_k Y_k(d))``, where TensoRF clamps
  ``relu(sum + 1/2)``) or ``mlp`` (TensoRF's ``MLP_Fea`` with the view direction as SH instead of its
  positional encoding, and without the features' encoding: ``c_max * sigmoid(MLP([B f, SH(d)]))``).

Planes are indexed ``[v, u]``: ``xy`` is (y, x), ``xz`` (z, x), ``yz`` (z, y); lines by their axis.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import drjit as dr

from mitsnerf.config import check_fields, param
from mitsnerf.fields.mlp import column, dense_apply, dense_init, rows_tensor
from mitsnerf.fields.sh import MAX_DEGREE, num_coefficients, sh_basis
from mitsnerf.math.activations import sigmoid, softplus
from mitsnerf.math.box import Box

#: The three (plane, line) pairs of a VM decomposition: plane key, its (u, v) unit axes, the line's axis.
PAIRS = (("xy", (0, 1), "z", 2), ("xz", (0, 2), "y", 1), ("yz", (1, 2), "x", 0))
SIGMA_RAW_MAX = 15.0
"""Largest pre-activation of the ``exp`` density (keeps float32 finite)."""


@dataclass(frozen=True)
class VMFieldConfig:
    """Sizes, activations and initialisation of the VM field (TensoRF's names in parentheses)."""

    density_components: int = param(16, lo=1, hi=64)
    """Components per plane of the density VM (``n_lamb_sigma``, TensoRF's 16). On the default cloud (1000 steps
    x 4096 rays) 8 density and 16 appearance components reached 38.32 dB on medium pixels, 16 and 24 38.83,
    16 and 48 39.06."""
    app_components: int = param(48, lo=1, hi=64)
    """Components per plane of the appearance VM (``n_lamb_sh``, TensoRF's 48)."""
    app_dim: int = param(0, lo=0, hi=256)
    """Output width of the basis matrix B (``data_dim_color``); 0: what the decode reads, ``3 (sh_degree + 1)^2``
    SH coefficients for ``sh``, TensoRF's 27 features for ``mlp``."""
    decode: str = param("sh", choices=("sh", "mlp"))
    """Colour from ``B f``: SH coefficients (TensoRF's ``SH`` render mode) or a small MLP (``MLP_Fea``). On the
    default cloud (1000 steps x 4096 rays, density shift -5, no priors) ``sh`` of degree 0 reached 38.20 dB on
    medium pixels in 45 s, ``mlp`` 37.99 dB in 58 s."""
    mlp_hidden: int = param(64, lo=1, hi=512)
    """Hidden width of the colour MLP (``featureC``, TensoRF: 128)."""
    mlp_layers: int = param(1, lo=0, hi=4)
    """Hidden layers of the colour MLP (TensoRF: 2)."""
    sh_degree: int = param(0, lo=0, hi=MAX_DEGREE)
    """SH band of the view direction: the MLP's direction input, or the ``sh`` decode's coefficients
    (0: no direction dependence; mitsnerf's media scatter isotropically)."""
    density_activation: str = param("softplus", choices=("softplus", "exp"))
    """``softplus`` (TensoRF's default) or ``exp`` of ``f + density_shift``."""
    density_shift: float = param(-3.0)
    """Added to the density feature before the activation. TensoRF's -10 starts the field empty
    (``25 softplus(-10) = 1e-3``) and, on the default cloud, had learned nothing after 300 steps (the
    gradients through ``softplus'(-10) = 5e-5`` sink under Adam's epsilon); -3 starts a haze of 1.2."""
    distance_scale: float = param(25.0, lo=0.0, lo_open=True)
    """Factor on the activated density (TensoRF's ``distance_scale``, 25)."""
    init_scale: float = param(0.1, lo=0.0, lo_open=True)
    """Vectors and planes start as ``init_scale * N(0, 1)`` (TensoRF: 0.1)."""
    c_max: float = param(1.0, lo=0.0, lo_open=True)
    """Largest colour (radiance) the decode can output."""

    def __post_init__(self) -> None:
        check_fields(self)
        sh = 3 * num_coefficients(self.sh_degree)
        if self.decode == "sh" and self.app_dim not in (0, sh):
            raise ValueError(f"app_dim: the sh decode of degree {self.sh_degree} reads 3 x "
                             f"{num_coefficients(self.sh_degree)} = {sh} coefficients (or give 0), got {self.app_dim}")

    @property
    def basis_width(self) -> int:
        """The basis matrix's output width: ``app_dim``, or the decode's own when 0.

        >>> VMFieldConfig().basis_width, VMFieldConfig(decode="mlp").basis_width, VMFieldConfig(sh_degree=1).basis_width
        (3, 27, 12)
        """
        if self.app_dim:
            return self.app_dim
        return 3 * num_coefficients(self.sh_degree) if self.decode == "sh" else 27


def grid_keys(kind: str) -> tuple[str, ...]:
    """The parameter keys of one VM (``kind``: ``density`` or ``app``): its three planes, then its three lines.

    >>> grid_keys("density")
    ('density.plane.xy', 'density.plane.xz', 'density.plane.yz', 'density.line.z', 'density.line.y', 'density.line.x')
    """
    return tuple(f"{kind}.plane.{p}" for p, _, _, _ in PAIRS) + tuple(f"{kind}.line.{a}" for _, _, a, _ in PAIRS)


GRID_KEYS = grid_keys("density") + grid_keys("app")
BASIS_KEY = "basis"


def grid_shape(key: str, resolution: int, channels: int) -> tuple[int, ...]:
    """(R, R, C) for a plane, (R, C) for a line."""
    return (resolution, resolution, channels) if ".plane." in key else (resolution, channels)


def _texture(tensor):
    import mitsuba as mi

    Texture = mi.Texture2f if tensor.ndim == 3 else mi.Texture1f
    return Texture(tensor, use_accel=False, filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)


def _lookup(tex, p, key: str) -> list:
    """The C channels (Floats) of plane or line ``key`` at unit points ``p``."""
    import mitsuba as mi

    kind = key.rsplit(".", 1)[1]
    if len(kind) == 2:
        u, v = ("xyz".index(kind[0]), "xyz".index(kind[1]))
        return list(tex.eval(mi.Point2f(p[u], p[v])))
    return list(tex.eval(mi.Point1f(p["xyz".index(kind)])))


def resample(tensor, resolution: int):
    """A plane (R, R, C) or line (R, C) resampled to ``resolution`` by its own (bi)linear lookup at the new
    texel centres, detached: the field changes only by the interpolation of an interpolation.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> line = mi.TensorXf([[0.0], [1.0]])                      # texel centres at 1/4 and 3/4
    >>> resample(line, 4).array                                 # centres 1/8 (clamped), 3/8, 5/8, 7/8 (clamped)
    [0, 0.25, 0.75, 1]
    """
    import mitsuba as mi

    TensorXf = type(tensor)
    Float = dr.leaf_t(TensorXf)
    UInt32 = dr.uint32_array_t(Float)
    r, channels = int(resolution), int(tensor.shape[-1])
    with dr.suspend_grad():
        tex = _texture(dr.detach(tensor))
        if tensor.ndim == 3:
            idx = dr.arange(UInt32, r * r)
            values = tex.eval(mi.Point2f((Float(idx % r) + 0.5) / r, (Float(idx // r) + 0.5) / r))
            shape: tuple[int, ...] = (r, r, channels)
        else:
            values = tex.eval(mi.Point1f((Float(dr.arange(UInt32, r)) + 0.5) / r))
            shape = (r, channels)
        out = TensorXf(dr.ravel(mi.ArrayXf(*values), order="F"), shape=shape)
        dr.eval(out)
    return out


def init_params(config: VMFieldConfig, resolution: int, TensorXf, seed: int) -> dict:
    """The VM field's parameters at ``resolution``: planes and lines ``init_scale * N(0, 1)`` (TensoRF's), the
    basis matrix and the MLP uniform Xavier (:func:`mitsnerf.fields.mlp.dense_init`), all from ``seed``."""
    rng = dr.rng(seed=seed)
    Float = dr.leaf_t(TensorXf)
    params: dict[str, Any] = {}
    for kind, channels in (("density", config.density_components), ("app", config.app_components)):
        for key in grid_keys(kind):
            shape = grid_shape(key, resolution, channels)
            params[key] = TensorXf(config.init_scale * rng.normal(Float, dr.prod(shape)), shape=shape)
    basis = dense_init([3 * config.app_components, config.basis_width], TensorXf, rng)
    params[BASIS_KEY] = basis["0.weights"]  # B has no bias (TensoRF's basis_mat)
    if config.decode == "mlp":
        n_in = config.basis_width + num_coefficients(config.sh_degree)
        sizes = [n_in] + [config.mlp_hidden] * config.mlp_layers + [3]
        params.update(dense_init(sizes, TensorXf, rng, "mlp."))
    return params


class VMField:
    """The field callable ``(x, d) -> (rgb, sigma)`` over the parameters of :func:`init_params`; also
    ``density(x)`` and ``density_feature(x)`` (``f``, before the activation).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> config = VMFieldConfig(density_shift=0.0, distance_scale=1.0)
    >>> f = VMField(config, init_params(config, 4, mi.TensorXf, 0), UNIT_BOX)
    >>> rgb, sigma = f(mi.Array3f([0.0, 0.1], 0.0, 0.0), mi.Array3f(0, 0, 1))
    >>> dr.width(rgb), bool(dr.all((sigma > 0.5) & (sigma < 1.0)))  # softplus of a feature near 0: about log 2
    (2, True)
    """

    def __init__(self, config: VMFieldConfig, params: Mapping[str, Any], box: Box) -> None:
        self.config = config
        self.box = box
        self.params = dict(params)
        self.textures = {key: _texture(self.params[key]) for key in GRID_KEYS}

    @property
    def resolution(self) -> int:
        return int(self.params["density.line.x"].shape[0])

    def _vm(self, kind: str, p) -> list:
        """The products plane x line of VM ``kind`` at unit points ``p``: 3 lists of C Floats (XY.Z, XZ.Y, YZ.X)."""
        out = []
        for plane, _, axis, _ in PAIRS:
            pk, lk = f"{kind}.plane.{plane}", f"{kind}.line.{axis}"
            m = _lookup(self.textures[pk], p, pk)
            v = _lookup(self.textures[lk], p, lk)
            out.append([a * b for a, b in zip(m, v)])
        return out

    def density_feature(self, x):
        """``f(x)`` of the density VM (the sum over planes and components), Float (M,)."""
        p = self.box.to_unit(x)
        return sum(sum(products) for products in self._vm("density", p))

    def activate(self, f):
        """``sigma`` from the density feature."""
        c = self.config
        if c.density_activation == "exp":
            return c.distance_scale * dr.exp(dr.minimum(f + c.density_shift, SIGMA_RAW_MAX))
        return c.distance_scale * softplus(f + c.density_shift)

    def density(self, x):
        """``sigma(x)``, Float (M,)."""
        return self.activate(self.density_feature(x))

    def app_features(self, x):
        """``B f_app(x)``: (M, basis_width) point-major tensor."""
        import mitsuba as mi

        p = self.box.to_unit(x)
        products = [v for group in self._vm("app", p) for v in group]
        return rows_tensor(mi.TensorXf, products, dr.width(x)) @ self.params[BASIS_KEY]

    def __call__(self, x, d):
        import mitsuba as mi

        c = self.config
        width = dr.width(x)
        if dr.width(d) != width:
            d = d + dr.zeros(type(d), width)
        sigma = self.density(x)
        feats = self.app_features(x)
        Y = sh_basis(d, c.sh_degree)
        if c.decode == "sh":
            k = len(Y)
            raw = [sum(column(feats, 3 * j + ch) * Y[j] for j in range(k)) for ch in range(3)]
        else:
            inputs = dr.concat([feats, rows_tensor(mi.TensorXf, Y, width)], axis=1)
            out = dense_apply(self.params, "mlp.", c.mlp_layers + 1, inputs)
            raw = [column(out, ch) for ch in range(3)]
        return type(x)(*(c.c_max * sigmoid(v) for v in raw)), sigma
