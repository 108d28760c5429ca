"""The scene: the data model (``model``), the scene-file loader (``loader``) and the mesh
sources it reads (``meshio`` for OBJ/PLY files, ``shapes`` for built-in shapes,
``subdivide`` for midpoint subdivision), and the readers of other tools' scenes
(``importers`` for OBJ + MTL and PLY, with ``objmtl`` and ``plyattrs``; ``mitsuba_xml``;
both make their scenes of mesh parts through ``parts``).
``load_scene`` reads any of them by suffix (``SCENE_FORMATS``)."""
from .importers import SCENE_FORMATS, auto_camera, load_scene
from .model import (
                    COMBINATIONS,
                    FALLOFFS,
                    LIGHT_SHAPES,
                    MAX_DEPTH_LIMIT,
                    SHADING_MODES,
                    SPAWN_RULES,
                    TERMINATOR_FIXES,
                    Camera,
                    Light,
                    Material,
                    ObjectInfo,
                    PointLight,
                    Scene,
                    SceneError,
                    Settings,
                    check_ranges,
                    precision_limits,
                    validate_image_size,
                    validate_settings,
)

__all__ = ["SCENE_FORMATS", "auto_camera", "COMBINATIONS", "FALLOFFS", "MAX_DEPTH_LIMIT",
           "SHADING_MODES", "SPAWN_RULES",
           "TERMINATOR_FIXES", "LIGHT_SHAPES", "Camera", "Light", "Material",
           "ObjectInfo", "PointLight", "Scene", "SceneError", "Settings", "check_ranges",
           "load_scene", "precision_limits", "validate_image_size", "validate_settings"]
