"""The registry of methods: name -> (config type, model type).

Adding a method is one module with a frozen config dataclass and a
:class:`mitsnerf.methods.base.Model`, plus one line below.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

from mitsnerf.errors import unknown
from mitsnerf.methods.mitsuba_inverse import MitsubaInverseConfig, MitsubaInverseModel
from mitsnerf.methods.nerf import NeRFMethodConfig, NeRFModel
from mitsnerf.methods.ngp import NGPMethodConfig, NGPModel
from mitsnerf.methods.voxel import VoxelMethodConfig, VoxelModel


@dataclass(frozen=True)
class MethodEntry:
    name: str
    config_type: type
    model_type: type
    description: str


METHODS = MappingProxyType(
    {
        "nerf": MethodEntry(
            "nerf", NeRFMethodConfig, NeRFModel, "positional-encoding MLPs, coarse + importance samples"
        ),
        "mitsuba-inverse": MethodEntry(
            "mitsuba-inverse",
            MitsubaInverseConfig,
            MitsubaInverseModel,
            "sigma_t/albedo grids through Mitsuba's prbvolpath, coarse to fine",
        ),
        "ngp": MethodEntry("ngp", NGPMethodConfig, NGPModel, "hash-grid encoding, tiny MLPs, occupancy-grid skipping"),
        "voxel": MethodEntry(
            "voxel", VoxelMethodConfig, VoxelModel, "dense density + SH grid, TV prior, coarse to fine"
        ),
    }
)


def get_method(name: str) -> MethodEntry:
    try:
        return METHODS[name]
    except KeyError:
        raise KeyError(unknown("method", name, sorted(METHODS))) from None
