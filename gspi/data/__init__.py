"""Dataset sources of GS-PI: the procedural PBR benchmark generator and importers.

One concept per module:
    lattice         the canonical V = 32 Fibonacci hemisphere lattice and its cameras
    sdf_shapes      implicit shape families (recipes, normalised to the unit sphere)
    sphere_trace    batched sphere tracing + autograd normals
    patterns        3D procedural patterns (noise, Voronoi, checker, stripes, glyphs)
    materials       spatially varying PBR material classes
    environments    procedural HDR lat-long environments (capture and held-out sets)
    scene_recipe    seeded scene recipes and scene splits
    render_view     supersampled split-sum rendering of views + exact GT maps
    render_scene    one scene in the canonical layout (incl. relit ground truth)
    point_clouds    GT point clouds of the lattice views (gt_points.npz)
    contact_sheet   per-scene preview PNG
    generate        the whole dataset (splits.json, workers, determinism)
    nerf_synthetic  NeRF-synthetic import/export
Entry point: `gspi-data` (gspi/cli/data.py).
"""
