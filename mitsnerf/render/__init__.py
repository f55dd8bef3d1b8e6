"""Rays, ray/box clipping, and the emission-absorption renderer that takes any field."""
