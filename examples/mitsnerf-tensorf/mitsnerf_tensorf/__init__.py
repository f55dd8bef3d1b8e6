"""TensoRF-VM for mitsnerf: an example of a method written outside the package, installed as a distribution
whose ``mitsnerf.methods`` entry point names :class:`TensoRFModel` (see this directory's README.md)."""

from mitsnerf_tensorf.field import VMField, VMFieldConfig
from mitsnerf_tensorf.model import TensoRFConfig, TensoRFModel

__all__ = ["TensoRFConfig", "TensoRFModel", "VMField", "VMFieldConfig"]
__version__ = "0.1.0"
