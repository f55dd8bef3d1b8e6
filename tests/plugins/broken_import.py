"""A plugin module that cannot be imported (its dependency is missing)."""

import mitsnerf_missing_dependency  # noqa: F401
