"""Capabilities are typed protocols, tested with isinstance: a model with a queryable medium is a HasField,
its field a DensityField; a model without one is neither, and the harness says so instead of probing."""

from __future__ import annotations

import pytest

from mitsnerf.fields.protocols import DensityField, Field
from mitsnerf.methods import methods
from mitsnerf.methods.base import HasField, Model, RayModel, ViewModel


class _NoField(Model):
    name = "nofield"

    def parameters(self):
        return {}

    def set_parameters(self, values):
        pass

    def render_view(self, camera, *, pixel_center=0.5, footprint=1):
        raise AssertionError("not rendered here")


@pytest.mark.parametrize("name", sorted(methods()))
def test_every_builtin_method_has_a_queryable_medium(name):
    assert issubclass(methods()[name].model_type, HasField)


def test_a_model_without_a_field_is_not_a_has_field():
    assert not isinstance(_NoField(None, None), HasField)


def test_a_density_field_is_a_field_with_density():
    class Fog:
        def __call__(self, x, d):
            return x, 1.0

    assert isinstance(Fog(), Field) and not isinstance(Fog(), DensityField)
    Fog.density = lambda self, x: 1.0
    assert isinstance(Fog(), DensityField)


def test_the_step_refuses_a_model_of_neither_protocol():
    from mitsnerf.train.step import step_loss

    assert not isinstance(_NoField(None, None), (RayModel, ViewModel))
    with pytest.raises(TypeError, match="RendersRays: subclass RayModel"):
        step_loss(_NoField(None, None), None, None, 0, None)
