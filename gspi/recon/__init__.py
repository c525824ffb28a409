"""Stage 0: fit a 2DGS asset to a canonical scene's input views (``gspi-recon``).

The paper starts from "a pre-trained 2DGS model"; this package produces one from the
scene's 32 lattice views by photometric optimisation (L1 + D-SSIM on display values,
visual-hull initialisation, progressive SH, 3DGS densify / prune schedule), and renders
the 32 canonical lattice views of any 2DGS asset in one call (``render_lattice_views``).
See docs/RECON.md.
"""

from gspi.recon.data import ReconInputError, SceneViews, load_scene_views
from gspi.recon.lattice_render import lattice_camera_tensors, render_lattice_views

__all__ = [
    "ReconInputError",
    "SceneViews",
    "lattice_camera_tensors",
    "load_scene_views",
    "render_lattice_views",
]
