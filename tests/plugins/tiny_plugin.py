"""Plugin methods for the registry's and the conformance suite's tests, registered by path through
MITSNERF_METHODS (``NAME=tests/plugins/tiny_plugin.py:CLASS``), as code that is not installed is."""

from __future__ import annotations

from mitsnerf.methods.ngp import NGPModel


class TinyNGP(NGPModel):
    """A trivial subclass of ngp: a method from outside the package that keeps every promise."""

    description = "ngp, registered from outside the package"


class FrozenNGP(NGPModel):
    """A plugin bug: the optimiser's values never reach the field (set_parameters drops them)."""

    description = "ngp whose set_parameters drops the values"

    def set_parameters(self, values) -> None:
        pass


def not_a_class():
    return None


class NoConfig(NGPModel):
    description = "a model whose config is not a MethodConfig"
    config_type = dict  # type: ignore[assignment]


class EmptyNGP(NGPModel):
    """A plugin bug: nothing to train (parameters() is empty)."""

    description = "ngp whose parameters() is empty"

    def parameters(self):
        return {}
