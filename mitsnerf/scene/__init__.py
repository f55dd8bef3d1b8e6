"""Scene specifications (the library: ``library/*.toml``), their Mitsuba scenes, and rendering the ground truth.

- :mod:`.spec`: parse and validate specs (:func:`load_scene`, :class:`SceneSpec`);
- :mod:`.rigs`: camera placements (:func:`camera_rig`);
- :mod:`.lights`, :mod:`.to_mitsuba`: the Mitsuba scene, sensors, and the background a NeRF sees;
- :mod:`.render`: each view of a split through ``volpath``, the true grids on disk.

Writing a whole dataset (cache, manifest, noise floor) is :func:`mitsnerf.generate.generate_dataset`.
"""
