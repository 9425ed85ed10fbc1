"""Builds one corpus scene in Blender from its layout (layout.py's JSON) and
renders the equirect panoramas at every probe and frame with Cycles on the CPU.

    blender -b --factory-startup --python scene.py -- SPEC.json OUT_DIR W H SAMPLES

Writes OUT_DIR/render/<id>.exr (float32, scene-linear RGB, ZIP) without the
small emitters (sphere lamps, the sun), which the camera does not see there,
and OUT_DIR/render/<id>.emitters.json: the share of each pixel those emitters
cover, unoccluded, with their radiance. build.py adds the two into the ground
truth. Each file is written to a temporary name and renamed, so an interrupted
build resumes where it stopped; existing files are kept. Prints one line per
panorama with its render time.

    blender -b --factory-startup --python scene.py -- SPEC.json OUT_DIR W H SAMPLES --seen

renders nothing: for each frame it reads OUT_DIR/render/<id>.bright.json (the
pixels build.py found above the SDR frame's white point) and writes
OUT_DIR/render/<id>.seen.json, whether some probe sees the surface point (or
the sky direction) each of those pixels sees.
"""

import json
import math
import os
import sys
import time

import bmesh
import bpy

STUDIO_WORLDS = os.path.join(os.path.dirname(bpy.app.binary_path), "..", "share", "blender", "datafiles",
                             "studiolights", "world")


def studio_world(name):
    for root in (STUDIO_WORLDS, "/usr/share/blender/datafiles/studiolights/world",
                 os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world")):
        p = os.path.join(root, name + ".exr")
        if os.path.isfile(p):
            return p
    raise SystemExit(f"Blender's captured world '{name}.exr' is not installed (datafiles/studiolights/world)")


def clear():
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    for m in list(bpy.data.meshes):
        bpy.data.meshes.remove(m)


def node(nt, kind, **inputs):
    n = nt.nodes.new(kind)
    for k, v in inputs.items():
        n.inputs[k].default_value = v
    return n


def new_material(name):
    """An empty node material: (material, node tree, output node)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    return mat, nt, nt.nodes.new("ShaderNodeOutputMaterial")


def surface_material(name, m):
    """Principled BSDF over a procedural texture evaluated at the world
    position (boxes are axis-aligned, so 3D textures wrap every face)."""
    mat, nt, out = new_material(name)
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    base, alt = tuple(m["base"]) + (1.0,), tuple(m["alt"]) + (1.0,)
    bsdf.inputs["Roughness"].default_value = m["roughness"]
    if m["surface"] == "mirror":
        bsdf.inputs["Metallic"].default_value = 1.0
        bsdf.inputs["Roughness"].default_value = 0.0
    else:
        bsdf.inputs["Specular"].default_value = 0.5 if m["surface"] == "glossy" else 0.3
    tex = m["texture"]
    if tex == "none":
        bsdf.inputs["Base Color"].default_value = base
    else:
        geo = nt.nodes.new("ShaderNodeNewGeometry")
        vec = geo.outputs["Position"]
        if tex == "brick":
            # Bricks run along the wall: (x + y, z) on walls, (x, y) on floors.
            sep = nt.nodes.new("ShaderNodeSeparateXYZ")
            nt.links.new(geo.outputs["Position"], sep.inputs[0])
            s = nt.nodes.new("ShaderNodeMath")
            s.operation = "ADD"
            nt.links.new(sep.outputs[0], s.inputs[0])
            nt.links.new(sep.outputs[1], s.inputs[1])
            wall = nt.nodes.new("ShaderNodeCombineXYZ")
            nt.links.new(s.outputs[0], wall.inputs[0])
            nt.links.new(sep.outputs[2], wall.inputs[1])
            nsep = nt.nodes.new("ShaderNodeSeparateXYZ")
            nt.links.new(geo.outputs["Normal"], nsep.inputs[0])
            absz = nt.nodes.new("ShaderNodeMath")
            absz.operation = "ABSOLUTE"
            nt.links.new(nsep.outputs[2], absz.inputs[0])
            flat = nt.nodes.new("ShaderNodeMath")
            flat.operation = "GREATER_THAN"
            nt.links.new(absz.outputs[0], flat.inputs[0])
            flat.inputs[1].default_value = 0.5
            mix = nt.nodes.new("ShaderNodeMix")
            mix.data_type = "VECTOR"
            nt.links.new(flat.outputs[0], mix.inputs["Factor"])
            nt.links.new(wall.outputs[0], mix.inputs[4])
            nt.links.new(geo.outputs["Position"], mix.inputs[5])
            vec = mix.outputs[1]
            t = nt.nodes.new("ShaderNodeTexBrick")
            t.inputs["Color1"].default_value = base
            t.inputs["Color2"].default_value = tuple(0.8 * c for c in m["base"]) + (1.0,)
            t.inputs["Mortar"].default_value = alt
            t.inputs["Scale"].default_value = m["scale"] * 0.6
            nt.links.new(vec, t.inputs["Vector"])
            nt.links.new(t.outputs["Color"], bsdf.inputs["Base Color"])
        elif tex == "checker":
            t = nt.nodes.new("ShaderNodeTexChecker")
            t.inputs["Color1"].default_value = base
            t.inputs["Color2"].default_value = alt
            t.inputs["Scale"].default_value = m["scale"]
            nt.links.new(vec, t.inputs["Vector"])
            nt.links.new(t.outputs["Color"], bsdf.inputs["Base Color"])
        else:
            kind = {"noise": "ShaderNodeTexNoise", "voronoi": "ShaderNodeTexVoronoi", "wave": "ShaderNodeTexWave"}[tex]
            t = nt.nodes.new(kind)
            t.inputs["Scale"].default_value = m["scale"]
            if tex == "noise":
                t.inputs["Detail"].default_value = 6.0
            nt.links.new(vec, t.inputs["Vector"])
            ramp = nt.nodes.new("ShaderNodeMix")
            ramp.data_type = "RGBA"
            fac = t.outputs["Distance"] if tex == "voronoi" else t.outputs["Fac"]
            nt.links.new(fac, ramp.inputs["Factor"])
            ramp.inputs[6].default_value = base
            ramp.inputs[7].default_value = alt
            nt.links.new(ramp.outputs[2], bsdf.inputs["Base Color"])
    nt.links.new(bsdf.outputs[0], out.inputs[0])
    return mat


def emission_material(name, colour, radiance):
    mat, nt, out = new_material(name)
    e = nt.nodes.new("ShaderNodeEmission")
    e.inputs["Color"].default_value = tuple(colour) + (1.0,)
    e.inputs["Strength"].default_value = radiance
    nt.links.new(e.outputs[0], out.inputs[0])
    return mat


def link(name, bm, mat, smooth=False):
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    if smooth:
        for p in mesh.polygons:
            p.use_smooth = True
    mesh.materials.append(mat)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def add_box(bm, lo, hi):
    v = [bm.verts.new((x, y, z)) for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])]
    for f in ((0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)):
        bm.faces.new([v[i] for i in f])


def build(spec):
    clear()
    mats = {name: surface_material(name, m) for name, m in spec["materials"].items()}
    by_mat = {}
    for b in spec["boxes"]:
        by_mat.setdefault(b["mat"], []).append(b)
    for name, boxes in by_mat.items():
        bm = bmesh.new()
        for b in boxes:
            add_box(bm, b["min"], b["max"])
        link("boxes_" + name, bm, mats[name])
    for k, s in enumerate(spec["spheres"]):
        bm = bmesh.new()
        bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=s["radius"])
        bmesh.ops.translate(bm, verts=bm.verts, vec=s["center"])
        link(f"sphere{k}", bm, mats[s["mat"]], smooth=True)
    for k, e in enumerate(spec["emitters"]):
        if e["shape"] == "sphere":
            sphere_light(f"lamp{k}", e)
            continue
        bm = bmesh.new()
        add_box(bm, e["min"], e["max"])
        link(f"emitter{k}", bm, emission_material(f"emit{k}", e["colour"], e["radiance"]))
    for k, p in enumerate(spec.get("portals", [])):
        light = bpy.data.lights.new(f"portal{k}", "AREA")
        light.shape = "RECTANGLE"
        light.size, light.size_y = p["size"]
        light.cycles.is_portal = True
        obj = bpy.data.objects.new(f"portal{k}", light)
        obj.location = p["center"]
        obj.rotation_euler = tuple(math.radians(v) for v in p["rotation_deg"])
        bpy.context.scene.collection.objects.link(obj)
    if spec.get("sun"):
        sun_light(spec["sun"])


# Small lamps and the sun are Cycles lights rather than emissive meshes: Cycles
# (3.4) samples mesh lights by area, so a far sun disc would starve every lamp,
# and its mesh-light set is ordered differently from run to run (the same seed
# gave other noise). Lights are sampled by solid angle and are not seen by camera
# rays; the camera sees them analytically (footprints()).
def sphere_light(name, e):
    """A sphere lamp of the layout's radiance L: Cycles gives a point light of
    power P and radius r the radiance P / (4 pi^2 r^2)."""
    peak = max(e["colour"])
    light = bpy.data.lights.new(name, "POINT")
    light.shadow_soft_size = e["radius"]
    light.color = tuple(c / peak for c in e["colour"])
    light.energy = e["radiance"] * peak * 4.0 * math.pi ** 2 * e["radius"] ** 2
    light.cycles.use_multiple_importance_sampling = True
    obj = bpy.data.objects.new(name, light)
    obj.location = e["center"]
    bpy.context.scene.collection.objects.link(obj)


def sun_light(sun):
    """The sun of the layout's radiance L and angular diameter a: Cycles gives a
    sun of strength S the radiance S / (pi tan^2(a / 2))."""
    from mathutils import Vector
    peak = max(sun["colour"])
    light = bpy.data.lights.new("sun", "SUN")
    light.angle = math.radians(sun["diameter_deg"])
    light.color = tuple(c / peak for c in sun["colour"])
    light.energy = sun["radiance"] * peak * math.pi * math.tan(light.angle / 2) ** 2
    obj = bpy.data.objects.new("sun", light)
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = Vector(sun["direction"]).to_track_quat("Z", "Y")
    bpy.context.scene.collection.objects.link(obj)


def world(spec):
    w = bpy.data.worlds.new("world")
    bpy.context.scene.world = w
    w.use_nodes = True
    nt = w.node_tree
    bg = nt.nodes["Background"]
    ws = spec["world"]
    if ws["kind"] == "black":
        bg.inputs["Strength"].default_value = 0.0
        bg.inputs["Color"].default_value = (0, 0, 0, 1)
        return 0.0
    if ws["kind"] == "sky":
        sky = nt.nodes.new("ShaderNodeTexSky")
        sky.sky_type = "NISHITA"
        sky.sun_disc = False
        sky.sun_elevation = math.radians(ws["sun_elevation_deg"])
        sky.sun_rotation = math.radians(ws["sun_azimuth_deg"])
        sky.air_density = ws["air"]
        sky.dust_density = ws["dust"]
        nt.links.new(sky.outputs[0], bg.inputs["Color"])
    else:
        tex = nt.nodes.new("ShaderNodeTexEnvironment")
        tex.image = bpy.data.images.load(studio_world(ws["name"]))
        coord = nt.nodes.new("ShaderNodeTexCoord")
        mp = nt.nodes.new("ShaderNodeMapping")
        mp.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(ws["rotation_deg"]))
        nt.links.new(coord.outputs["Generated"], mp.inputs["Vector"])
        nt.links.new(mp.outputs[0], tex.inputs["Vector"])
        nt.links.new(tex.outputs[0], bg.inputs["Color"])
    # Scale the sky so that its median over the upper hemisphere is the layout's
    # unit (1 by day, `median` at night): measured on a small world-only render.
    bg.inputs["Strength"].default_value = 1.0
    med = world_median()
    target = ws.get("median", 1.0)
    strength = target / med if med > 0 else 1.0
    bg.inputs["Strength"].default_value = strength
    return strength


def camera():
    sc = bpy.context.scene
    cam = bpy.data.cameras.new("pano")
    cam.type = "PANO"
    cam.cycles.panorama_type = "EQUIRECTANGULAR"
    cam.clip_start = 0.01
    cam.clip_end = 1.0e6
    obj = bpy.data.objects.new("pano", cam)
    sc.collection.objects.link(obj)
    sc.camera = obj
    obj.rotation_mode = "XYZ"
    return obj


def settings(w, h, samples, seed):
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = samples
    sc.cycles.use_adaptive_sampling = False
    sc.cycles.use_denoising = False
    sc.cycles.seed = seed
    sc.cycles.max_bounces = 8
    sc.cycles.diffuse_bounces = 4
    sc.cycles.glossy_bounces = 4
    sc.cycles.transmission_bounces = 0
    sc.cycles.volume_bounces = 0
    sc.cycles.transparent_max_bounces = 2
    sc.cycles.caustics_reflective = False
    sc.cycles.caustics_refractive = False
    sc.cycles.blur_glossy = 1.0
    sc.cycles.sample_clamp_direct = 0.0
    sc.cycles.sample_clamp_indirect = 0.0
    # Box filter of one pixel: a pixel is the mean radiance over its (u, v)
    # square, which is what the analytic footprints add.
    sc.cycles.pixel_filter_type = "BOX"
    sc.cycles.filter_width = 1.0
    sc.render.use_persistent_data = True
    sc.render.resolution_x, sc.render.resolution_y = w, h
    sc.render.resolution_percentage = 100
    sc.render.use_file_extension = False
    sc.view_settings.view_transform = "Standard"
    s = sc.render.image_settings
    s.file_format = "OPEN_EXR"
    s.color_depth = "32"
    s.color_mode = "RGB"
    s.exr_codec = "ZIP"


def render_to(path):
    sc = bpy.context.scene
    tmp = path + ".part"
    sc.render.filepath = tmp
    bpy.ops.render.render(write_still=True)
    os.replace(tmp, path)


def world_median():
    """Median luminance of the world alone over the upper hemisphere, from a
    64 x 32 render with nothing in the scene."""
    import tempfile
    sc = bpy.context.scene
    keep = (sc.render.resolution_x, sc.render.resolution_y, sc.cycles.samples)
    hidden = [o for o in sc.objects if o.type == "MESH"]
    for o in hidden:
        o.hide_render = True
    cam = sc.camera
    cam.location = (0.0, 0.0, 0.0)
    cam.rotation_euler = (math.radians(90), 0.0, 0.0)
    sc.render.resolution_x, sc.render.resolution_y, sc.cycles.samples = 64, 32, 16
    path = os.path.join(tempfile.mkdtemp(), "world.exr")
    render_to(path)
    img = bpy.data.images.load(path)
    px = list(img.pixels)
    ch = img.channels
    lum = []
    for row in range(16, 32):  # Blender's image rows run bottom-up: the upper half
        for col in range(64):
            i = (row * 64 + col) * ch
            lum.append(0.2126 * px[i] + 0.7152 * px[i + 1] + 0.0722 * px[i + 2])
    bpy.data.images.remove(img)
    for o in hidden:
        o.hide_render = False
    sc.render.resolution_x, sc.render.resolution_y, sc.cycles.samples = keep
    lum.sort()
    return lum[len(lum) // 2]


def small_emitters(spec):
    """(centre, angular-radius function, radiance, colour, ray length limit) of
    every emitter the camera sees analytically: sphere lamps and the sun."""
    out = []
    for e in spec["emitters"]:
        if e["shape"] == "sphere":
            out.append(("sphere", e["center"], e["radius"], e["radiance"], e["colour"]))
    sun = spec.get("sun")
    if sun:
        out.append(("sun", sun["direction"], math.radians(sun["diameter_deg"] / 2), sun["radiance"], sun["colour"]))
    return out


def footprints(spec, position, rotation, w, h, sub=8):
    """What the camera at `position` with world_from_camera `rotation` sees of
    each small emitter: [(row, col, coverage)] per emitter, coverage being the
    share of the pixel's (u, v) square (sub x sub samples) whose ray meets the
    emitter unoccluded (occlusion by a scene ray cast). A point-sampled tiny
    sun or lamp would leave its pixels to Monte Carlo chance."""
    from mathutils import Vector
    depsgraph = bpy.context.evaluated_depsgraph_get()
    sc = bpy.context.scene
    cam = Vector(position)
    inv = rotation.transposed()
    result = []
    for kind, where, size, radiance, colour in small_emitters(spec):
        if kind == "sun":
            axis, alpha, limit = Vector(where).normalized(), size, 1.0e4
        else:
            to = Vector(where) - cam
            dist = to.length
            if dist <= size * 1.01:
                continue
            axis, alpha, limit = to / dist, math.asin(size / dist), dist - size - 1e-3
        c = inv @ axis  # camera axes: x right, y up, -z forward
        theta = math.asin(max(-1.0, min(1.0, c.y)))
        phi = math.atan2(c.x, -c.z)
        pad = alpha + 2.0 * math.pi / w
        r0 = max(0, int(((0.5 - (theta + pad) / math.pi) * h)))
        r1 = min(h - 1, int(((0.5 - (theta - pad) / math.pi) * h)))
        if abs(theta) + pad > math.radians(80.0):
            cols = range(w)
        else:
            half = pad / max(math.cos(abs(theta) + pad), 1e-3)
            c0 = int(math.floor((phi - half) / (2 * math.pi) * w + w / 2))
            c1 = int(math.floor((phi + half) / (2 * math.pi) * w + w / 2))
            cols = [cc % w for cc in range(c0, c1 + 1)]
        cos_alpha = math.cos(alpha)
        pixels = []
        for row in range(r0, r1 + 1):
            for col in cols:
                hits = 0
                for i in range(sub):
                    for j in range(sub):
                        u = (col + (j + 0.5) / sub) / w
                        v = (row + (i + 0.5) / sub) / h
                        ph, th = (u - 0.5) * 2 * math.pi, (0.5 - v) * math.pi
                        d = rotation @ Vector((math.cos(th) * math.sin(ph), math.sin(th), -math.cos(th) * math.cos(ph)))
                        if d.dot(axis) < cos_alpha:
                            continue
                        hit = sc.ray_cast(depsgraph, cam, d, distance=limit)[0]
                        hits += not hit
                if hits:
                    pixels.append([row, col, hits / (sub * sub)])
        if pixels:
            result.append({"kind": kind, "radiance": radiance, "colour": colour, "pixels": pixels})
    return result


def pixel_ray(rotation, row, col, w, h):
    from mathutils import Vector
    ph, th = ((col + 0.5) / w - 0.5) * 2 * math.pi, (0.5 - (row + 0.5) / h) * math.pi
    return rotation @ Vector((math.cos(th) * math.sin(ph), math.sin(th), -math.cos(th) * math.cos(ph)))


def seen_by_probes(spec, position, rotation, pixels, w, h):
    """For each (row, col) of the camera at `position`: 1 when some probe sees
    what the pixel's centre ray sees (the first surface point it meets, from
    the side it faces, unoccluded; or, for a ray to the sky, the same sky
    direction unoccluded), else 0. Small emitters (lamps, sun) are not geometry
    here; their footprints answer for them."""
    from mathutils import Vector
    depsgraph = bpy.context.evaluated_depsgraph_get()
    sc = bpy.context.scene
    cam = Vector(position)
    probes = [Vector(p["position"]) for p in spec["probes"]]
    out = []
    for row, col in pixels:
        d = pixel_ray(rotation, row, col, w, h)
        hit, x, normal = sc.ray_cast(depsgraph, cam, d, distance=1.0e4)[:3]
        seen = 0
        for p in probes:
            if not hit:
                seen = int(not sc.ray_cast(depsgraph, p, d, distance=1.0e4)[0])
            else:
                to = x - p
                dist = to.length
                if dist < 1e-4:
                    seen = 1
                elif normal.dot(-to) > 0.0:
                    seen = int(not sc.ray_cast(depsgraph, p, to / dist, distance=dist - 1e-3)[0])
            if seen:
                break
        out.append(seen)
    return out


def seen_mode(spec, out, w, h):
    from mathutils import Euler
    raw = os.path.join(out, "render")
    for view in spec["frames"]:
        src = os.path.join(raw, view["id"] + ".bright.json")
        dst = os.path.join(raw, view["id"] + ".seen.json")
        if os.path.isfile(dst) or not os.path.isfile(src):
            continue
        t = time.time()
        pixels = json.load(open(src))
        yaw, pitch, roll = view["yaw_pitch_roll_deg"]
        rot = Euler((math.radians(90 + pitch), math.radians(roll), math.radians(yaw)), "XYZ").to_matrix()
        seen = seen_by_probes(spec, view["position"], rot, pixels, w, h)
        with open(dst + ".part", "w") as f:
            json.dump(seen, f)
        os.replace(dst + ".part", dst)
        print(f"seen {view['id']}: {sum(seen)} of {len(seen)} bright pixels in {time.time() - t:.2f} s", flush=True)


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    spec_path, out, w, h, samples = argv[0], argv[1], int(argv[2]), int(argv[3]), int(argv[4])
    spec = json.load(open(spec_path))
    if "--seen" in argv[5:]:
        build(spec)
        seen_mode(spec, out, w, h)
        return
    samples *= spec["scene"].get("samples_factor", 1)
    settings(w, h, samples, spec["seed"])
    build(spec)
    cam = camera()
    strength = world(spec)
    print(f"world strength {strength:.6g}, {samples} samples", flush=True)
    os.makedirs(os.path.join(out, "probes"), exist_ok=True)
    os.makedirs(os.path.join(out, "path"), exist_ok=True)
    from mathutils import Euler
    raw = os.path.join(out, "render")
    os.makedirs(raw, exist_ok=True)
    for view in spec["probes"] + spec["frames"]:
        path = os.path.join(raw, view["id"] + ".exr")
        if os.path.isfile(path):
            continue
        yaw, pitch, roll = view["yaw_pitch_roll_deg"]
        euler = (math.radians(90 + pitch), math.radians(roll), math.radians(yaw))
        cam.location = view["position"]
        cam.rotation_euler = euler
        t = time.time()
        fp = footprints(spec, view["position"], Euler(euler, "XYZ").to_matrix(), w, h)
        tmp = path[:-4] + ".emitters.json.part"
        with open(tmp, "w") as f:
            json.dump(fp, f)
        os.replace(tmp, path[:-4] + ".emitters.json")
        render_to(path)
        print(f"rendered {view['id']} in {time.time() - t:.2f} s", flush=True)


main()
