"""What are renders of a dataset's split scored against? Its :class:`Reference`, loaded once
(:func:`load_reference`) and handed to everything that scores renders of that split.

A :class:`Reference` holds the split's ground-truth images and cameras, the box, the true ``sigma_t``
(and an anisotropic medium's similarity-scaled one, :func:`mitsnerf.scoring.density.reduced_extinction`),
the medium pixels (:func:`mitsnerf.scoring.medium.medium_masks`) and the manifest's noise floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mitsnerf.math.box import Box
from mitsnerf.scoring.density import reduced_extinction
from mitsnerf.scoring.medium import medium_masks


@dataclass(frozen=True)
class Reference:
    """What renders of one split are scored against, and everything known about that split."""

    images: np.ndarray
    """(V, H, W, 3) linear RGB, the split's ground truth."""
    cameras: tuple
    pixel_center: float
    box: Box
    sigma_t: np.ndarray | None
    """The true extinction grid (None for foreign data)."""
    masks: np.ndarray | None
    """(V, H, W) medium pixels (None without a true grid)."""
    noise_floor: dict | None
    """The manifest's ``noise_floor`` (None without ``test_ref``)."""
    reduced_sigma_t: np.ndarray | None = None
    """An anisotropic medium's similarity-scaled extinction (:func:`mitsnerf.scoring.density.reduced_extinction`);
    None otherwise."""


def _reduced_sigma_t(dataset, sigma_t: np.ndarray | None) -> np.ndarray | None:
    """The dataset's :func:`mitsnerf.scoring.density.reduced_extinction` when its spec's medium is
    Henyey-Greenstein with ``g != 0``."""
    from mitsnerf.data.arrays import read_npy
    from mitsnerf.data.dataset import true_grid_path

    phase = (((dataset.manifest or {}).get("spec") or {}).get("volume") or {}).get("phase") or {}
    g = float(phase.get("g", 0.0)) if phase.get("type") == "hg" else 0.0
    albedo = true_grid_path(dataset.root, "albedo")
    if sigma_t is None or g == 0.0 or not albedo.exists():
        return None
    return reduced_extinction(sigma_t, read_npy(albedo, "numpy grid"), g)


def load_true_sigma_t(root) -> np.ndarray | None:
    """The ground-truth ``sigma_t`` grid of a generated dataset (None for foreign data)."""
    from mitsnerf.data.arrays import read_npy
    from mitsnerf.data.dataset import true_grid_path

    path = true_grid_path(root)
    if not path.exists():
        return None
    return read_npy(path, "numpy grid")


def load_reference(dataset, split: str = "test") -> Reference:
    """The :class:`Reference` of a :class:`mitsnerf.data.dataset.Dataset` split (masks from its true grid): load it
    once and pass it to whatever scores renders of that split."""
    views = dataset.views(split)
    sigma_t = load_true_sigma_t(dataset.root)
    masks = medium_masks(sigma_t, dataset.box, views.cameras, views.pixel_center) if sigma_t is not None else None
    floor = (dataset.manifest or {}).get("noise_floor") if split == "test" else None
    return Reference(views.images, tuple(views.cameras), views.pixel_center, dataset.box, sigma_t, masks, floor,
                     _reduced_sigma_t(dataset, sigma_t))
