"""Loads equirect HDR files into headless Blender as a world environment and
prints, per file, what Blender read: size, channel means and maxima (JSON, one
line per file, prefixed with "LUMIPROBE "). A real client of `lumiprobe
export`'s .hdr and .exr files, run by tests/export.rs:

    blender -b --factory-startup --python tools/blender/load_env.py -- FILE...
"""
import json
import sys

import bpy

files = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
world = bpy.data.worlds.new("lumiprobe")
world.use_nodes = True
bpy.context.scene.world = world
nodes = world.node_tree.nodes
env = nodes.new("ShaderNodeTexEnvironment")
background = nodes["Background"]
world.node_tree.links.new(env.outputs["Color"], background.inputs["Color"])
for path in files:
    img = bpy.data.images.load(path, check_existing=False)
    env.image = img
    w, h = img.size
    px = list(img.pixels)  # RGBA floats, rows bottom to top
    n = w * h
    means = [sum(px[c::4]) / n for c in range(3)]
    maxima = [max(px[c::4]) for c in range(3)]
    print("LUMIPROBE " + json.dumps({
        "file": path,
        "size": [w, h],
        "float": bool(img.is_float),
        "mean": means,
        "max": maxima,
        "world_image": world.node_tree.nodes[env.name].image.name == img.name,
    }))
    sys.stdout.flush()
