"""vtrack: 3D visuo-tactile reconstruction and in-hand object tracking.

Importing this package is cheap on purpose: heavy back-ends (torch, open3d, depthai,
pyvista, viser) are imported only by the components a scene or command actually uses.

Conventions used across the package:
- lengths in metres, angles in radians, unless a name says otherwise (``_mm``, ``_deg``, ``_px``);
- transforms are 4x4 homogeneous matrices named ``T_a_b``: they map points expressed in
  frame ``b`` into frame ``a`` (``p_a = T_a_b @ p_b``);
- timestamps are float64 seconds.
"""

from vtrack.errors import InputError, VtrackError

__version__ = "0.1.0"

__all__ = ["InputError", "VtrackError", "__version__"]
