"""Things a renderer can query at (x, d): ground-truth grids, voxel grids, networks.

Every field is a callable ``field(x, d) -> (rgb, sigma)`` on Array3f positions and
directions of width M, returning Array3f colour and Float extinction of width M.
"""
