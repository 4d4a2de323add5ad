"""Scene files: pydantic models, YAML load/save, ``--set`` overrides, error messages with file,
line and field path.

A scene is everything needed to repeat a run: fabric (size, divisions, warp/weft tables),
constraints, the initial deformation, the mold, the optional terms of eq. (1) and the solver
settings. Units are SI (m, N, Pa, N/m).

The modules, by job: :mod:`.schema` (fabric, panels, constraints, solver settings),
:mod:`.scene` (``Scene``, stages), :mod:`.molds` (the typed mold specs and their union),
:mod:`.fields` (the shared field checks), :mod:`.sourcelines` (YAML line lookup,
:func:`format_validation_error`), :mod:`.overrides` (``--set`` paths) and :mod:`.load` (files
and dicts to a validated Scene, the stages' scenes). Every name is re-exported here: ``from
clothsim.config import X`` is the way to use them.
"""

from ..errors import SceneError  # noqa: F401  (re-exported: clothsim.config.SceneError)
from ..strict import Strict as _Strict  # noqa: F401
from .fields import (COORD_MAX, DENSITY_MAX, G_MAX, MOLD_PRIMITIVES, SEAM_STIFFNESS_MAX,  # noqa: F401
                     _MOLD_TAGS, Int, _coords, _direction, _finite, _finite3, _nonzero3, _positive,
                     _short, _strict_int)
from .load import (dump_scene, load_scene, read_yaml, scene_from_dict, stage_scenes,  # noqa: F401
                   validate_mold_spec)
from .molds import (FRICTION_MAX, BoxMoldSpec, BoxParams, CylinderMoldSpec, CylinderParams,  # noqa: F401
                    LegMoldSpec, MeshMoldSpec, MoldSpec, PlaneMoldSpec, PlaneParams, SphereMoldSpec, SphereParams,
                    _mold_tag, _MoldFriction, _MoldHolder)
from .overrides import _set_path, apply_overrides, parse_overrides  # noqa: F401
from .scene import REST_SCALE_RANGE, STAGE_FIELDS, Scene, Stage  # noqa: F401
from .schema import (NODE_SETS, SOLVER_METHODS, Constraint, Fabric, Gravity, IndexRange,  # noqa: F401
                     Initial, MaterialSpec, NodeRange, Panel, PanelPlacement, PanelTransform,
                     PatternRef, Region, Seam, SolverSettings, SpringTerm, Wrap, WrapHull)
from .sourcelines import (_TAG, _blamed, _clean_loc, _in_file, _is_tag, _winning_branches,  # noqa: F401
                          _yaml_line, format_validation_error)
