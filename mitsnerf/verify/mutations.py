"""Bugs planted inside the package's own functions, as a real bug would sit: every case must see them.

A :class:`Mutation` names a function (module and qualified name), an exact snippet of its
source and the snippet's replacement. :func:`planted` takes ``inspect.getsource`` of the
function, replaces the snippet (it must occur exactly once), compiles the result in the
function's own module globals and swaps the function's ``__code__`` for the compiled one,
restoring it on exit (also when the body raises). The function object stays the same, so
every caller -- ``render_rays``, the Mitsuba plugin, the methods, anything that imported
the function by name -- runs the bug. ``mitsnerf check --mutations`` runs every case
under every mutation and prints which cases catch it
(:func:`mitsnerf.verify.runner.run_mutations`).

The correct quadrature, for reference (:mod:`mitsnerf.math.composite`,
:func:`mitsnerf.math.sampling.stratified_t`)::

    t_i = t_n + (i + u_i) h,   delta_i = t_{i+1} - t_i (last: t_f - t_{N-1})
    T_i = exp(-sum_{j<i} sigma_j delta_j),   C = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i + T_N bg

Value mutations change what is rendered; training mutations only what training renders
(jittered samples); gradient mutations only derivatives (``x s - detach(x) (s - 1)`` has the
value of ``x`` and the gradient ``s dx``).

>>> from drjit.llvm import Float
>>> from mitsnerf.math.composite import weights
>>> with planted(MUTATIONS["T_off_by_one"]):
...     w_bug, _ = weights(Float(1.0, 1.0), Float(1.0, 1.0), 2)
>>> w_bug  # T_i includes its own interval: e^-1 (1 - e^-1), e^-2 (1 - e^-1)
[0.232544, 0.0855482]
>>> weights(Float(1.0, 1.0), Float(1.0, 1.0), 2)[0]  # restored: (1 - e^-1), e^-1 (1 - e^-1)
[0.632121, 0.232544]
"""

from __future__ import annotations
import __future__

import contextlib
import importlib
import inspect
import textwrap
from collections.abc import Iterator
from dataclasses import dataclass


@dataclass(frozen=True)
class Mutation:
    """A bug: in ``module.qualname``, the source ``snippet`` (exactly once) becomes ``replacement``."""

    name: str
    description: str
    module: str
    qualname: str
    snippet: str
    replacement: str
    kind: str = "value"
    """``"value"`` (changes what is rendered), ``"training"`` (only jittered, training-mode
    rendering) or ``"gradient"`` (only derivatives)."""

    @property
    def where(self) -> str:
        return f"{self.module.rsplit('.', 1)[-1]}.{self.qualname}"


class MutationError(RuntimeError):
    """A mutation no longer applies to the current source (its snippet is gone or ambiguous)."""


def target(m: Mutation):
    """The function object ``m`` mutates."""
    obj = importlib.import_module(m.module)
    for part in m.qualname.split("."):
        obj = getattr(obj, part)
    if not inspect.isfunction(obj):
        raise MutationError(f"{m.name}: {m.module}.{m.qualname} is not a plain Python function")
    return obj


def mutated_code(m: Mutation):
    """The code object of ``m``'s function with the snippet replaced (raises :class:`MutationError`)."""
    func = target(m)
    lines, first_line = inspect.getsourcelines(func)
    source = textwrap.dedent("".join(lines))
    count = source.count(m.snippet)
    if count != 1:
        raise MutationError(f"{m.name}: the snippet occurs {count} times in {m.module}.{m.qualname} "
                            f"(needs exactly 1); update the mutation to the current source:\n{m.snippet}")
    mutated = source.replace(m.snippet, m.replacement)
    # Keep the line numbers of the file, so a traceback through the mutated code points at it.
    code = compile("\n" * (first_line - 1) + mutated, inspect.getsourcefile(func) or m.module, "exec",
                   flags=__future__.annotations.compiler_flag, dont_inherit=True)
    namespace = dict(func.__globals__)
    exec(code, namespace)
    new = namespace[func.__name__]
    if new.__code__.co_freevars != func.__code__.co_freevars:
        raise MutationError(f"{m.name}: {m.qualname} is a closure; only module-level functions can be mutated")
    return new.__code__


@contextlib.contextmanager
def planted(m: Mutation | None) -> Iterator[None]:
    """Run the body with ``m`` planted in its function (None: no mutation); always restores."""
    if m is None:
        yield
        return
    func = target(m)
    original = func.__code__
    func.__code__ = mutated_code(m)
    try:
        yield
    finally:
        func.__code__ = original


_COMPOSITE = "mitsnerf.math.composite"
_SAMPLING = "mitsnerf.math.sampling"

MUTATION_LIST: tuple[Mutation, ...] = (
    Mutation(
        "T_off_by_one", "T_i = exp(-sum_{j<=i} sigma_j delta_j): each sample's own interval included",
        _COMPOSITE, "weights",
        "T = dr.exp(-dr.block_prefix_sum(tau, n, exclusive=True))",
        "T = dr.exp(-dr.block_prefix_sum(tau, n, exclusive=False))",
    ),
    Mutation(
        "wrong_interval", "alpha_i and T from exp(-sigma_i delta_{i+1}): each density times the next "
        "interval (the last keeps its own)",
        _COMPOSITE, "weights",
        "    tau = sigma * delta\n",
        "    _k = dr.arange(dr.uint32_array_t(type(delta)), dr.width(delta))\n"
        "    _last = _k % n == n - 1\n"
        "    tau = sigma * dr.select(_last, delta, dr.gather(type(delta), delta, _k + 1, ~_last))\n",
    ),
    Mutation(
        "background_T_before_last", "background weighted by T_{N-1} (before the last interval) instead of T_N",
        _COMPOSITE, "composite",
        "+ T_final * background",
        "+ (T_final + dr.gather(type(w), w, dr.arange(dr.uint32_array_t(type(delta)), dr.width(T_final)) * n + n - 1))"
        " * background",
    ),
    Mutation(
        "no_background", "the background term T_N bg dropped",
        _COMPOSITE, "composite",
        "+ T_final * background", "+ 0.0 * T_final",
    ),
    Mutation(
        "delta_x1.01", "every interval 1% too long",
        _SAMPLING, "stratified_t",
        "    return t, delta\n", "    return t, delta * 1.01\n",
    ),
    Mutation(
        "delta_wrong_end", "delta_i = t_i - t_{i-1} (t_{-1} = t_n): each sample takes the interval before it",
        _SAMPLING, "stratified_t",
        "        delta = t_next - t\n",
        "        delta = t - dr.select(i == 0, tn, tn + (fi - 1 + dr.gather(Float, u, idx - 1, i > 0)) / n * span)\n",
    ),
    Mutation(
        "jitter_ignored", "the training jitter u ignored: every sample at the left edge of its stratum",
        _SAMPLING, "stratified_t",
        "        u_next = dr.gather(Float, u, idx + 1, i + 1 < n)\n",
        "        u = dr.zeros(Float, n_rays * n)\n        u_next = u\n",
        kind="training",
    ),
    Mutation(
        "jitter_frozen", "the same training jitter at every step (the step's generator ignores the step)",
        "mitsnerf.train.schedule", "step_rng",
        "| (int(step) & 0xFFFFFFFF)", "| 0",
        kind="training",
    ),
    Mutation(
        "T_detached", "T_i cut from the AD graph (gradients through alpha and T_N only)",
        _COMPOSITE, "weights",
        "    T = dr.exp(-dr.block_prefix_sum(tau, n, exclusive=True))\n",
        "    T = dr.detach(dr.exp(-dr.block_prefix_sum(tau, n, exclusive=True)))\n",
        kind="gradient",
    ),
    Mutation(
        "rgb_detached", "the colour c_i cut from the AD graph",
        _COMPOSITE, "composite",
        "dr.block_sum(w * rgb, n)", "dr.block_sum(w * dr.detach(rgb), n)",
        kind="gradient",
    ),
    Mutation(
        "tau_grad_x1.003", "the gradient of sigma_i delta_i (through T and alpha) 0.3% too large",
        _COMPOSITE, "weights",
        "    tau = sigma * delta\n",
        "    tau = sigma * delta * 1.003 - dr.detach(sigma * delta) * 0.003\n",
        kind="gradient",
    ),
    Mutation(
        "rgb_grad_x1.003", "the gradient of the colour c_i 0.3% too large",
        _COMPOSITE, "composite",
        "dr.block_sum(w * rgb, n)", "dr.block_sum(w * (rgb * 1.003 - dr.detach(rgb) * 0.003), n)",
        kind="gradient",
    ),
    Mutation(
        "C_grad_x1.003", "the gradient of the composited colour C 0.3% too large",
        _COMPOSITE, "composite",
        "    opacity = one_minus_exp_neg(", "    color = color * 1.003 - dr.detach(color) * 0.003\n"
        "    opacity = one_minus_exp_neg(",
        kind="gradient",
    ),
    Mutation(
        "hg_sign", "Henyey-Greenstein with the sign of g flipped: forward scattering becomes backward",
        "mitsnerf.math.phase", "hg",
        "1.0 + g * g - 2.0 * g * cos_theta", "1.0 + g * g + 2.0 * g * cos_theta",
    ),
    Mutation(
        "cosine_reversed", "the scattering angle's cosine taken against the reversed view direction (-d)",
        "mitsnerf.math.phase", "scattering_cosine",
        "zip(_xyz(w), _xyz(d))", "zip(_xyz(w), _xyz(-d))",
    ),
    Mutation(
        "light_direction_flipped", "a directional light arriving from the way it travels (the sun behind the medium)",
        "mitsnerf.scene.lights", "light_terms",
        "(-dr.normalize(Array3f(*light.direction))", "(dr.normalize(Array3f(*light.direction))",
    ),
    Mutation(
        "phase_factor_missing", "the single-scattering field's phase function left out (each light's irradiance "
        "scattered with weight 1)",
        "mitsnerf.fields.scatter", "ScatterField.single_scatter",
        "E * T * hg(scattering_cosine(w, d), self.g)", "E * T",
    ),
    Mutation(
        "drt_no_ratio_weight", "differential ratio tracking without the ratio-tracking transmittance in its "
        "reservoir weights: every tentative point as likely, wherever the medium has already stopped the light",
        "mitsnerf.render.drt", "drt_weight",
        "return dr.mean(transmittance) / sigma_bar", "return dr.mean(transmittance) ** 0 / sigma_bar",
        kind="gradient",
    ),
    Mutation(
        "majorant_below_density", "the majorant grid at half the densest voxel each cell reads: tracking "
        "meets sigma_t > sigma_bar",
        "mitsnerf.render.tracking", "majorant_grid",
        "bound = peak * np.float32(MAJORANT_MARGIN)",
        "bound = peak * np.float32(0.5)",
    ),
    Mutation(
        "extinction_first_channel", "a chromatic grid's red extinction taken for every colour channel",
        "mitsnerf.fields.grid", "extinction",
        "Array3f(channels[0], channels[1], channels[2])", "Array3f(channels[0], channels[0], channels[0])",
    ),
)

MUTATIONS: dict[str, Mutation] = {m.name: m for m in MUTATION_LIST}
"""Name -> mutation."""
