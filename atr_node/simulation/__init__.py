"""Target signature simulation and synthetic missions (SPEC section 4).

Modules, in the order a signature is made:

- :mod:`.meshes`: built-in target meshes, STL/OBJ loading, placement with heading and burial;
- :mod:`.raytrace`: geometric-optics tracer -> per-pixel ``p_shadow`` and echo strength ``e``;
- :mod:`.performance`: sonar equation (Francois-Garrison, Lambert, noise, multipath) ->
  shadow and echo contrast ratios per range;
- :mod:`.signature`: SAS along-track beam (Q_SAS), gray levels, speckle, blending;
- :mod:`.inject`: :func:`inject_targets`, the API calibration uses, with exact truth;
- :mod:`.seabed`: synthetic K-distributed backgrounds, ripples, drop-outs;
- :mod:`.world`: legs, targets, clutter and ripple fields of a mission (:func:`plan_world`);
- :mod:`.ins`: the INS of a mission as NMEA and CAN records;
- :mod:`.mission`: :func:`generate_mission`, the lawnmower mission of ``atr-node simulate``.
"""

from .inject import InjectedTarget, Placement, anchor_column, inject_targets
from .meshes import BUILTIN_SHAPES, Mesh, builtin_mesh, load_mesh, place
from .mission import MissionFiles, generate_mission
from .performance import Levels, SonarModel, francois_garrison_db_per_km, q_sas
from .raytrace import Signature, trace
from .seabed import gain_curve, seabed_pixels

__all__ = [
    "BUILTIN_SHAPES", "InjectedTarget", "Levels", "Mesh", "MissionFiles", "Placement", "Signature", "SonarModel",
    "anchor_column", "builtin_mesh", "francois_garrison_db_per_km", "gain_curve", "generate_mission",
    "inject_targets", "load_mesh", "place", "q_sas", "seabed_pixels", "trace",
]
