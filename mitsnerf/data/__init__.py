"""Datasets on disk: images, cameras, grids, manifests."""
