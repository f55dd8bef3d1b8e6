"""Scene specifications (``scenes/*.toml``), their Mitsuba scenes, and ground-truth datasets.

- :mod:`.spec`: parse and validate specs (:func:`load_scene`, :class:`SceneSpec`);
- :mod:`.rigs`: camera placements (:func:`camera_rig`);
- :mod:`.lights`, :mod:`.to_mitsuba`: the Mitsuba scene, sensors, and the background a NeRF sees;
- :mod:`.generate`: render a spec into a dataset directory (:func:`generate_dataset`).
"""

from mitsnerf.scene.generate import (
    FORMAT_VERSION,
    dataset_dir,
    generate_all,
    generate_dataset,
    medium_mask,
    read_manifest,
)
from mitsnerf.scene.lights import SKY_TO_WORLD, bake_sky, envmap_eval, sky_radiance
from mitsnerf.scene.rigs import camera_positions, camera_rig
from mitsnerf.scene.spec import (
    LIGHT_TYPES,
    RIGS,
    UP,
    CameraRigSpec,
    ConstantLight,
    DirectionalLight,
    LightSpec,
    PointLight,
    RenderSpec,
    SceneSpec,
    SkyLight,
    VolumeSpec,
    list_scenes,
    load_scene,
    parse_scene,
    scenes_dir,
)
from mitsnerf.scene.to_mitsuba import background_description, scene_dict, sensor_dict, volume_grids

__all__ = [
    "FORMAT_VERSION", "LIGHT_TYPES", "RIGS", "SKY_TO_WORLD", "UP",
    "CameraRigSpec", "ConstantLight", "DirectionalLight", "LightSpec", "PointLight", "RenderSpec",
    "SceneSpec", "SkyLight", "VolumeSpec",
    "background_description", "bake_sky", "camera_positions", "camera_rig", "dataset_dir",
    "envmap_eval", "generate_all", "generate_dataset", "list_scenes", "load_scene", "medium_mask",
    "parse_scene", "read_manifest", "scene_dict", "scenes_dir", "sensor_dict", "sky_radiance",
    "volume_grids",
]
