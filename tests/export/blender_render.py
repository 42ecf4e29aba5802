"""Runs inside Blender (`blender -b --factory-startup --python blender_render.py -- JOB.json`),
started by check_blender_render.py: builds each exported material.py on Blender's factory scene,
checks what the user sees, renders it with Cycles on the CPU at the job's camera and point-light
configurations, and compares each texel with `anisocap render`'s image of the same configuration.

Rendering: one perspective camera at the configuration's camera position looking at the material's
centre, a point light of zero radius at the light's position, a black world, direct light only,
a box pixel filter of 0.01 pixel (each pixel is the radiance of the one point its centre sees).
A second render of the same camera with the plane emitting its UV coordinates tells which point of
the material each pixel sees; a texel's value is that of the pixel, near the projection of its
centre, whose point lies in the texel closest to its centre (at least 3 pixels lie between texel
centres; texels with no pixel inside are left out and counted).

Light units: anisocap's point light of intensity I gives a white Lambertian texel the radiance
cos(theta) I / (pi d^2) (render/configurations.hpp). The Cycles point light's power P is set to
I times a factor measured here on a white Lambertian plane (the radiance per watt at 1 unit), and
the plane's render is checked against the formula at every texel.

Writes JOB's "out" file: {"lambert": relative L1, "families": {name: {config: {"error", "texels",
"left_out"}}}, "checks": [...]}."""
import array
import json
import math
import os
import runpy
import shutil
import sys

import bpy
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

job = json.load(open(sys.argv[sys.argv.index("--") + 1]))
width, height = job["width"], job["height"]
work = job["work"]
checks = []


def fail(message):
    print("blender_render: " + message, flush=True)
    sys.exit(1)


def factory_scene():
    bpy.ops.wm.read_factory_settings(use_empty=False)
    if "Cube" not in bpy.data.objects:
        fail("the factory scene has no default cube to test with")


def build_material(script, as_text_editor=False):
    """Runs material.py as Blender's command line does, or as the Text Editor does (__file__ inside a .blend)."""
    if as_text_editor:
        fake = os.path.join(work, "scene.blend", "material.py")
        source = open(script).read()
        exec(compile(source, fake, "exec"), {"__name__": "__main__", "__file__": fake})
    else:
        runpy.run_path(script, run_name="__main__")
    plane = bpy.data.objects.get("anisocap sample")
    if plane is None or not plane.data.materials:
        fail(f"{script}: no plane 'anisocap sample' with a material")
    return plane


def check_user_view(script, plane):
    """The factory cube is gone, and the script's camera sees the whole plane with nothing in front."""
    scene = bpy.context.scene
    if "Cube" in bpy.data.objects:
        fail(f"{script}: the factory cube is still in the scene")
    if scene.camera is None or scene.camera.name != "anisocap camera":
        fail(f"{script}: the scene's camera is not the script's")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for corner in [(-0.45, -0.45), (0.45, -0.45), (-0.45, 0.45), (0.45, 0.45), (0.0, 0.0)]:  # the plane's mesh spans +-0.5
        point = plane.matrix_world @ Vector((corner[0], corner[1], 0.0))
        co = world_to_camera_view(scene, scene.camera, point)
        if not (0 <= co.x <= 1 and 0 <= co.y <= 1 and co.z > 0):
            fail(f"{script}: the camera does not see the plane's point {tuple(point)}")
        origin = scene.camera.matrix_world.translation
        direction = (point - origin).normalized()
        hit, location, _, _, obj, _ = scene.ray_cast(depsgraph, origin, direction)
        if not hit or obj.name != plane.name:
            fail(f"{script}: the camera's view of the plane's point {tuple(point)} is blocked by {obj.name if hit else 'nothing (miss)'}")
    lights = [o for o in scene.objects if o.type == "LIGHT"]
    if not any(o.name == "anisocap light" for o in lights):
        fail(f"{script}: no light added")
    checks.append(f"{os.path.basename(os.path.dirname(script))}: cube removed, camera sees the whole plane unobstructed")


def render_setup():
    scene = bpy.context.scene
    for obj in list(scene.objects):
        if obj.name != "anisocap sample":
            bpy.data.objects.remove(obj, do_unlink=True)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = 0
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 0.01
    scene.cycles.seed = 0
    scene.render.threads_mode = "FIXED"
    scene.render.threads = int(os.environ.get("OMP_NUM_THREADS", "2"))
    if scene.world is None:
        scene.world = bpy.data.worlds.new("black")
    scene.world.use_nodes = False
    scene.world.color = (0.0, 0.0, 0.0)
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.resolution_percentage = 100
    camera = bpy.data.objects.new("test camera", bpy.data.cameras.new("test camera"))
    light = bpy.data.objects.new("test light", bpy.data.lights.new("test light", "POINT"))
    light.data.shadow_soft_size = 0.0
    if hasattr(light.data, "use_soft_falloff"):
        light.data.use_soft_falloff = False
    scene.collection.objects.link(camera)
    scene.collection.objects.link(light)
    scene.camera = camera
    return scene, camera, light


def texel_centre(i, j, size_x, size_y):
    return Vector(((i + 0.5) / width * size_x - size_x / 2, size_y / 2 - (j + 0.5) / height * size_y, 0.0))


def place(scene, camera, light, config, size_x, size_y, watts_per_intensity):
    """Camera at the configuration's position looking at the centre, the frame fitted to the plane with
    at least 3 pixels between neighbouring texel centres; the light's power from its intensity."""
    position = Vector(config["camera"])
    camera.location = position
    camera.rotation_euler = (-position).to_track_quat("-Z", "Y").to_euler()
    camera.data.type = "PERSP"
    camera.data.sensor_fit = "HORIZONTAL"
    camera.data.clip_start = 1e-3
    bpy.context.view_layer.update()
    to_camera = camera.matrix_world.inverted()

    def tangent(p):
        c = to_camera @ p
        return (c.x / -c.z, c.y / -c.z)

    corners = [tangent(Vector((sx * size_x / 2, sy * size_y / 2, 0.0))) for sx in (-1, 1) for sy in (-1, 1)]
    ext_x = 1.03 * max(abs(c[0]) for c in corners)
    ext_y = 1.03 * max(abs(c[1]) for c in corners)
    spacing = math.inf
    for j in range(0, height, max(1, height // 8)):
        for i in range(0, width - 1, max(1, width // 8)):
            a = tangent(texel_centre(i, j, size_x, size_y))
            b = tangent(texel_centre(i + 1, j, size_x, size_y))
            c = tangent(texel_centre(i, min(j + 1, height - 1), size_x, size_y)) if j + 1 < height else None
            spacing = min(spacing, math.dist(a, b))
            if c is not None:
                spacing = min(spacing, math.dist(a, c))
    pixel = spacing / 3
    res_x = min(1600, math.ceil(2 * ext_x / pixel))
    res_y = min(1600, max(8, round(res_x * ext_y / ext_x)))
    scene.render.resolution_x, scene.render.resolution_y = res_x, res_y
    camera.data.angle = 2 * math.atan(ext_x)
    light.location = Vector(config["light"])
    light.data.energy = config["intensity"] * watts_per_intensity
    bpy.context.view_layer.update()


class Pixels:
    """An image's RGB values: at(row, column), row 0 at the bottom (Blender's order) unless top_first."""

    def __init__(self, path, top_first=False):
        image = bpy.data.images.load(path)
        self.width, self.height = image.size[0], image.size[1]
        self.values = array.array("f", [0.0]) * (self.width * self.height * 4)
        image.pixels.foreach_get(self.values)
        bpy.data.images.remove(image)
        self.top_first = top_first

    def at(self, row, column):
        if self.top_first:
            row = self.height - 1 - row
        k = 4 * (row * self.width + column)
        return self.values[k:k + 3].tolist()


def render(scene, path):
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    return Pixels(path)


def with_material(plane, material, action):
    saved = plane.data.materials[0]
    plane.data.materials[0] = material
    try:
        return action()
    finally:
        plane.data.materials[0] = saved


def emission_material(name, colour_from_uv):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    nodes.clear()
    output = nodes.new("ShaderNodeOutputMaterial")
    if colour_from_uv:
        shader = nodes.new("ShaderNodeEmission")
        uv = nodes.new("ShaderNodeUVMap")
        uv.uv_map = "UVMap"
        links.new(uv.outputs["UV"], shader.inputs["Color"])
        shader.inputs["Strength"].default_value = 1.0
    else:
        shader = nodes.new("ShaderNodeBsdfDiffuse")
        shader.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        shader.inputs["Roughness"].default_value = 0.0
    links.new(shader.outputs[0], output.inputs["Surface"])
    return material


def texel_pixels(scene, camera, plane, size_x, size_y, tag):
    """For each texel, the pixel near the projection of its centre whose point (from the UV render)
    lies in the texel and closest to its centre, with that point; texels with no such pixel are left out."""
    uv = with_material(plane, emission_material("uv", True), lambda: render(scene, os.path.join(work, f"uv_{tag}.exr")))
    res_x, res_y = scene.render.resolution_x, scene.render.resolution_y
    pixels = {}
    for j in range(height):
        for i in range(width):
            co = world_to_camera_view(scene, camera, texel_centre(i, j, size_x, size_y))
            px, py = int(co.x * res_x), int(co.y * res_y)
            best = None
            for qy in range(py - 2, py + 3):
                for qx in range(px - 2, px + 3):
                    if not (0 <= qx < res_x and 0 <= qy < res_y):
                        continue
                    u, v, _ = uv.at(qy, qx)
                    if int(math.floor(u * width)) != i or int(math.floor((1 - v) * height)) != j:
                        continue
                    offset = math.hypot(u * width - (i + 0.5), (1 - v) * height - (j + 0.5))
                    if best is None or offset < best[0]:
                        best = (offset, (qy, qx), Vector(((u - 0.5) * size_x, (v - 0.5) * size_y, 0.0)))
            if best is not None:
                pixels[(i, j)] = (best[1], best[2])
    return pixels


def main():
    families = job["families"]
    # The Text Editor: __file__ inside a .blend; the textures come from the folder written into the script.
    factory_scene()
    plane = build_material(job["editor_script"], as_text_editor=True)
    check_user_view(job["editor_script"], plane)
    # A script whose folder moved and whose __file__ is inside a .blend cannot find its textures: a clear error.
    factory_scene()
    try:
        build_material(families[0]["script"], as_text_editor=True)
        fail("a moved export run from the Text Editor found textures it should not have")
    except RuntimeError as error:
        if "TEXTURES" not in str(error):
            fail(f"unclear error for a moved export: {error}")
        checks.append("moved export from the Text Editor: " + str(error).split(":")[0] + ": clear error naming TEXTURES")

    # Light units on a white Lambertian plane: measure the radiance per watt, then check the falloff.
    factory_scene()
    plane = build_material(families[0]["script"])
    size_x, size_y = plane.scale[0], plane.scale[1]
    scene, camera, light = render_setup()
    white = emission_material("white", False)
    results = {"families": {}, "configs": job["configs"]}
    pixel_maps = {}
    lambert_errors = []
    watts_per_intensity = None
    for config in job["configs"]:
        place(scene, camera, light, config, size_x, size_y, 1.0)
        pixel_maps[config["name"]] = texel_pixels(scene, camera, plane, size_x, size_y, config["name"])
        img = with_material(plane, white, lambda: render(scene, os.path.join(work, f"white_{config['name']}.exr")))
        measured, expected = [], []
        lpos = Vector(config["light"])
        for (py, px), p in pixel_maps[config["name"]].values():  # the point the pixel sees, from its UV
            d = lpos - p
            expected.append(max(0.0, d.z / d.length) * config["intensity"] / (math.pi * d.length_squared))
            measured.append(img.at(py, px)[0])
        if watts_per_intensity is None:
            watts_per_intensity = sum(expected) / sum(measured)
        lambert_errors.append(sum(abs(m * watts_per_intensity - e) for m, e in zip(measured, expected)) / sum(expected))
    results["watts_per_intensity"] = watts_per_intensity
    results["lambert"] = max(lambert_errors)
    checks.append(f"Cycles point light: {watts_per_intensity:.6g} W per unit of anisocap intensity; "
                  f"white Lambertian plane within {100 * results['lambert']:.3f}% relative L1 in every configuration")

    for family in families:
        factory_scene()
        plane = build_material(family["script"])
        check_user_view(family["script"], plane)
        scene, camera, light = render_setup()
        per_config = {}
        for config in job["configs"]:
            place(scene, camera, light, config, size_x, size_y, watts_per_intensity)
            img = render(scene, os.path.join(work, f"{family['name']}_{config['name']}.exr"))
            reference = Pixels(family["renders"][config["name"]], top_first=True)
            difference = ours = theirs = 0.0
            texels = 0
            for (i, j), ((py, px), _) in pixel_maps[config["name"]].items():
                a, b = img.at(py, px), reference.at(j, i)
                difference += sum(abs(x - y) for x, y in zip(a, b))
                ours, theirs, texels = ours + sum(a), theirs + sum(b), texels + 1
            per_config[config["name"]] = {
                "error": difference / max(theirs, 1e-12),
                "brightness": ours / max(theirs, 1e-12),
                "texels": texels,
                "left_out": width * height - texels,
            }
        results["families"][family["name"]] = per_config
        print(f"blender_render: {family['name']}: " + ", ".join(f"{k} {100 * v['error']:.1f}%" for k, v in per_config.items()), flush=True)
    results["checks"] = checks
    results["blender"] = bpy.app.version_string
    json.dump(results, open(job["out"], "w"), indent=1)


try:
    main()
except SystemExit:
    raise
except BaseException as error:  # any failure inside Blender is a test failure, not a hang
    import traceback
    traceback.print_exc()
    sys.exit(1)
sys.exit(0)
