"""Render scene descriptions with Blender Cycles: runs INSIDE Blender's own Python (bpy only).

    blender -b --factory-startup -t 1 -P blender_render.py -- scene1.json [scene2.json ...]

Each scene JSON (written by `experiments.second_world.scenes`) gives the OBJ (one object per part,
named part_NN, Y up), per part the map files or constants and the UV scale, the HDRI with its
rotation and strength, the camera (position and target in the mesh's Y-up frame, horizontal fov)
and the output paths. Two renders per scene: the beauty pass (Cycles path tracing, transparent
film, view transform Standard set explicitly, PNG RGBA 16 bit) and the part-index mask (one
emission value per part, 1 sample, no pixel filter, view transform Raw, PNG 8 bit).
No project import here: Blender's Python does not have the project's dependencies.
"""

import json
import math
import sys

import bpy
from mathutils import Vector


def to_blender(p):
    """Y-up (x, y, z) -> Blender's Z-up (x, -z, y), as the OBJ importer maps forward -Z / up Y."""
    return Vector((p[0], -p[2], p[1]))


def reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def image_node(nodes, path, colour):
    node = nodes.new("ShaderNodeTexImage")
    node.image = bpy.data.images.load(path, check_existing=True)
    node.image.colorspace_settings.name = "sRGB" if colour else "Non-Color"
    node.interpolation = "Cubic"
    return node


def part_material(spec):
    """Principled BSDF fed by the part's maps through a UV scale/rotation (the project's tile formula)."""
    mat = bpy.data.materials.new(spec["object"] + "_mat")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    coords = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (spec["uv_scale"], spec["uv_scale"], 1.0)
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, spec.get("uv_rotation", 0.0))
    links.new(coords.outputs["UV"], mapping.inputs["Vector"])

    def feed(key, socket, colour):
        value = spec[key]
        if isinstance(value, str):
            tex = image_node(nodes, value, colour)
            links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
            links.new(tex.outputs["Color"], bsdf.inputs[socket])
        else:
            bsdf.inputs[socket].default_value = value

    feed("albedo", "Base Color", True)
    feed("roughness", "Roughness", False)
    feed("metallic", "Metallic", False)
    if spec.get("normal"):
        tex = image_node(nodes, spec["normal"], False)
        links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
        normal = nodes.new("ShaderNodeNormalMap")
        links.new(tex.outputs["Color"], normal.inputs["Color"])
        links.new(normal.outputs["Normal"], bsdf.inputs["Normal"])
    return mat


def index_material(spec, count):
    """Flat emission of value index/255: the mask pass writes the part index as the pixel value."""
    mat = bpy.data.materials.new(spec["object"] + "_index")
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    emit = nodes.new("ShaderNodeEmission")
    value = spec["index"] / 255.0
    emit.inputs["Color"].default_value = (value, value, value, 1.0)
    emit.inputs["Strength"].default_value = 1.0
    mat.node_tree.links.new(emit.outputs["Emission"], nodes["Material Output"].inputs["Surface"])
    return mat


def set_materials(objects, mats):
    for name, mat in mats.items():
        obj = objects[name]
        obj.data.materials.clear()
        obj.data.materials.append(mat)


def world(scene, hdri):
    w = bpy.data.worlds.new("hdri")
    scene.world = w
    w.use_nodes = True
    nodes, links = w.node_tree.nodes, w.node_tree.links
    background = nodes["Background"]
    background.inputs["Strength"].default_value = hdri["strength"]
    env = nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(hdri["path"], check_existing=True)
    coords = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, hdri["rotation"])
    links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    links.new(env.outputs["Color"], background.inputs["Color"])
    return w


def camera(scene, cam):
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "HORIZONTAL"
    data.angle = math.radians(cam["fov_deg"])
    data.clip_start, data.clip_end = 0.01, 100.0
    obj = bpy.data.objects.new("camera", data)
    scene.collection.objects.link(obj)
    obj.location = to_blender(cam["position"])
    direction = to_blender(cam["target"]) - obj.location
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
    scene.camera = obj


def render(scene, path, png_depth):
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.image_settings.color_depth = png_depth
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)


def render_scene(desc):
    reset()
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.render.resolution_x = scene.render.resolution_y = desc["resolution"]
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.render.dither_intensity = 0.0
    scene.cycles.seed = desc["seed"]
    scene.cycles.use_animated_seed = False
    bpy.ops.wm.obj_import(filepath=desc["mesh"], forward_axis="NEGATIVE_Z", up_axis="Y")
    objects = {o.name: o for o in scene.objects if o.type == "MESH"}
    for obj in objects.values():
        for poly in obj.data.polygons:
            poly.use_smooth = True
    camera(scene, desc["camera"])
    world(scene, desc["hdri"])

    # beauty: path tracing, Standard view transform (not Blender's default Filmic)
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = desc.get("exposure", 0.0)
    scene.view_settings.gamma = 1.0
    scene.cycles.samples = desc["samples"]
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = bool(desc.get("denoise", False))  # Debian's build has no OIDN
    scene.cycles.max_bounces = 6
    scene.cycles.filter_width = 1.5
    set_materials(objects, {p["object"]: part_material(p) for p in desc["parts"]})
    render(scene, desc["outputs"]["beauty"], "16")

    # mask: the part index per pixel, exact (1 sample, no filter, no colour transform, no background)
    scene.view_settings.view_transform = "Raw"
    scene.view_settings.exposure = 0.0
    scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.cycles.filter_width = 0.01
    scene.cycles.max_bounces = 0
    set_materials(objects, {p["object"]: index_material(p, len(desc["parts"])) for p in desc["parts"]})
    render(scene, desc["outputs"]["mask"], "8")


def main(argv):
    args = argv[argv.index("--") + 1:] if "--" in argv else []
    for path in args:
        with open(path) as handle:
            desc = json.load(handle)
        try:
            render_scene(desc)
        except Exception as exc:  # one bad scene costs one exemplar, the batch goes on
            print(f"SECOND_WORLD_FAILED {path}: {type(exc).__name__}: {exc}", flush=True)
            continue
        print(f"SECOND_WORLD_DONE {path}", flush=True)


main(sys.argv)
