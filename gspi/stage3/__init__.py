"""Stage III (paper, "Distilling PBR Attributes onto Gaussian Primitives"): staged targets ->
per-Gaussian albedo / roughness / metallic, exported as a PBR-GS PLY and canonical maps.

targets.py (staged per-view targets), init.py (back-projection initialisation), loss.py
(masked L1 / L2 / SSIM objective), render.py (material maps), distill.py (the loop),
export.py (maps at any cameras, canonical prediction layout). See docs/STAGE3.md.
"""
