"""Real assets: glTF/GLB PBR objects read, rendered and imported as scenes, and path tracing.

    gltf            glTF 2.0 / GLB reader (meshes, PBR materials, textures, node transforms)
    mesh_render     split-sum views + exact GT maps of a textured PBR mesh (trimesh ray casting)
    glb_import      `gspi-data import.glb=...`: an asset -> a scene in the canonical layout
    pathtrace       Mitsuba 3 path-traced input views (`data.renderer=pathtraced`)
"""
