"""Scene files (docs/SCENES.md): parse, validate and plan; encode ``OUT/<name>.scene.json``.

The work is split by responsibility, and this module gathers the public names:
``scene_types`` (the format's constants and parsed types), ``scene_load`` (parsing, validation,
instance transforms), ``scene_plan`` (LOD level selection and what to build of each model),
``scene_materials`` (attributes the materials use, shared materials of hand-made LOD lists),
``scene_output`` (the engine's scene file).

Pure: reads only the scene JSON and checks that the files it names exist; writes nothing.

* :func:`load_scene` parses one scene file into a :class:`Scene` (strict: an unknown key, a
  wrong type, a missing file or a bad transform is a :class:`SceneError` whose one line names
  the scene, the object index and the problem).
* :func:`plan_scene` turns the scenes of one build into what to build: one
  :class:`ModelPlan` per distinct model (a file, or a hand-made LOD list), with the union of
  every object's needs (view distances, on-screen size, texture budget), the LOD distance
  range whose levels can be selected, the texture size, and human-readable skip reasons.
* :func:`select_levels` says which LOD levels can be selected for a distance range;
  :func:`attributes_needed` which vertex attributes the materials use;
  :func:`check_shared_materials` whether the files of a hand-made LOD list share materials.
* :func:`encode_scene_output` writes the engine's scene file.

Conventions (see docs/SCENES.md): column vectors (``p' = M @ p``); the ops of an instance
compose in list order as ``M = O1 @ O2 @ ... @ On`` (each op post-multiplies, as glm's
``translate(M, t)`` / ``scale(M, s)`` / ``rotate(M, a, axis)``), so the *last* op acts on the
vertex first: ``[{"translation": t}, {"scaling": s}]`` scales in place, then places at ``t``.
Rotations are in degrees, right-handed (counter-clockwise looking down the axis towards the
origin). Distances are from the camera to the instance's origin, world units.
"""

from __future__ import annotations

from assetpipe.scene_types import (  # noqa: F401 (re-exported)
    INSTANCE_OPS,
    MODEL_EXTENSIONS,
    ModelKey,
    ModelUse,
    SCENE_FORMAT_VERSION,
    Scene,
    SceneObject,
    TEXTURE_EXTENSIONS,
)
from assetpipe.scene_load import (  # noqa: F401 (re-exported)
    compose_ops,
    load_scene,
    max_stretch,
    op_matrix,
    scene_name,
)
from assetpipe.scene_plan import (  # noqa: F401 (re-exported)
    ModelPlan,
    ScenePlan,
    distance_for_screen_px,
    level_at,
    next_pow2,
    plan_scene,
    select_levels,
    sphere_screen_px,
)
from assetpipe.scene_materials import (  # noqa: F401 (re-exported)
    attribute_reasons,
    attributes_needed,
    check_shared_materials,
)
from assetpipe.scene_output import (  # noqa: F401 (re-exported)
    encode_scene_output,
)
