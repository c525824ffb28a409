"""The procedural PBR benchmark generator: implicit shapes, material classes and their patterns,
seeded scene recipes, and the supersampled split-sum rendering of a scene's views with exact GT maps.

    sdf_shapes      implicit shape families (recipes, normalised to the unit sphere)
    sphere_trace    batched sphere tracing + autograd normals
    patterns        3D procedural patterns (noise, Voronoi, checker, stripes, glyphs)
    materials       spatially varying PBR material classes (MATERIAL_CLASSES)
    material_parts  objects of several parts, each its own class (data.parts)
    scene_recipe    seeded scene recipes and scene splits
    render_view     supersampled split-sum rendering of views + exact GT maps
    render_scene    one scene in the canonical layout (incl. relit ground truth)
"""
