"""Stage 0: fit a 2DGS asset to a canonical scene's input views (``gspi-recon``).

The paper starts from "a pre-trained 2DGS model"; this package produces one from the
scene's 32 lattice views by photometric optimisation (L1 + D-SSIM on display values,
visual-hull initialisation, progressive SH, 3DGS densify / prune schedule). The lattice
renderer every stage shares is ``gspi.gaussians.lattice_render``. See docs/RECON.md.
"""

from gspi.recon.data import ReconInputError, SceneViews, load_scene_views

__all__ = [
    "ReconInputError",
    "SceneViews",
    "load_scene_views",
]
