"""Imports a mesh scantex wrote into Blender and prints what Blender made of it, as one JSON
line after `SCANTEX_JSON `: faces, materials in use, and per material the image its base
colour reads with the image's size (0 x 0 when Blender could not load the file), and the
range of u over the UV layer. Run as
`blender --background --factory-startup --python import_pages.py -- <model.obj|model.glb>`."""
import json
import sys

import bpy

# Debian's Blender 3.4 glTF importer uses `numpy.bool`, which Debian's numpy 1.24 no longer
# has; the alias it stood for is the builtin.
try:
    import numpy

    if not hasattr(numpy, "bool"):
        numpy.bool = bool
except ImportError:
    pass

path = sys.argv[sys.argv.index("--") + 1]
bpy.ops.wm.read_factory_settings(use_empty=True)
if path.endswith(".obj"):
    bpy.ops.wm.obj_import(filepath=path)
else:
    bpy.ops.import_scene.gltf(filepath=path)
meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
faces = sum(len(o.data.polygons) for o in meshes)
materials = {}
u_lo, u_hi = float("inf"), float("-inf")
for o in meshes:
    used = {p.material_index for p in o.data.polygons}
    for k, slot in enumerate(o.material_slots):
        m = slot.material
        if m is None or k not in used:
            continue
        images = []
        if m.use_nodes:
            for n in m.node_tree.nodes:
                if n.type == "TEX_IMAGE" and n.image is not None:
                    images.append([n.image.filepath or n.image.name, n.image.size[0], n.image.size[1]])
        materials[m.name] = images
    uv = o.data.uv_layers.active
    if uv is not None:
        for d in uv.data:
            u_lo, u_hi = min(u_lo, d.uv[0]), max(u_hi, d.uv[0])
print("SCANTEX_JSON " + json.dumps({"faces": faces, "materials": materials, "u": [u_lo, u_hi]}))
