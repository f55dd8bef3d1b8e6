"""Pure functions: sampling along rays, compositing, metrics. No scene objects, no fields."""
