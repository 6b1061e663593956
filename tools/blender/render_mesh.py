"""Renders surface meshes (PLY or OBJ) with Blender, headless, on the CPU.

    blender -b --factory-startup --python tools/blender/render_mesh.py -- \
        --mesh a.ply [--mesh b.ply ...] --out shot.png \
        [--camera X Y Z --target X Y Z --lens MM] [--size 480 320] [--samples 16]

Every mesh is imported and shaded as liquid (a bluish glossy material),
lit by a sun and a sky; without --camera the camera frames the meshes'
bounding box from the front (looking along -z, y up, as the scenes are
set up). Used by `make gallery` (tools/gallery.py) and for the pictures
of docs/surfaces.md.
"""

import argparse
import math
import sys

import bpy
from mathutils import Vector


def parse():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="render_mesh.py")
    p.add_argument("--mesh", action="append", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--camera", type=float, nargs=3)
    p.add_argument("--target", type=float, nargs=3)
    p.add_argument("--lens", type=float, default=40.0)
    p.add_argument("--size", type=int, nargs=2, default=(480, 320))
    p.add_argument("--samples", type=int, default=16)
    return p.parse_args(argv)


def liquid_material():
    m = bpy.data.materials.new("liquid")
    m.use_nodes = True
    bsdf = m.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.18, 0.45, 0.85, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.15
    bsdf.inputs["Specular"].default_value = 0.6
    return m


def import_mesh(path):
    if path.endswith(".ply"):
        bpy.ops.import_mesh.ply(filepath=path)
    else:
        bpy.ops.import_scene.obj(filepath=path, axis_forward="-Z", axis_up="Y")
    obj = bpy.context.selected_objects[0]
    # Files are Y-up; Blender is Z-up: turn the object, not the data.
    if path.endswith(".ply"):
        obj.rotation_euler = (math.radians(90), 0, 0)
    bpy.ops.object.shade_smooth()
    return obj


def main():
    a = parse()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    material = liquid_material()
    objects = [import_mesh(m) for m in a.mesh]
    for o in objects:
        o.data.materials.append(material)
    bpy.context.view_layer.update()
    corners = [o.matrix_world @ Vector(c) for o in objects for c in o.bound_box]
    lo = Vector([min(c[i] for c in corners) for i in range(3)])
    hi = Vector([max(c[i] for c in corners) for i in range(3)])
    centre, size = (lo + hi) / 2, (hi - lo).length

    def blender(v):  # a scene's Y-up point in Blender's Z-up frame
        return Vector((v[0], -v[2], v[1]))

    cam_data = bpy.data.cameras.new("camera")
    cam_data.lens = a.lens
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    cam.location = blender(a.camera) if a.camera else centre + Vector((0.35 * size, -1.6 * size, 0.55 * size))
    target = blender(a.target) if a.target else centre
    cam.rotation_euler = (target - cam.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam

    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (math.radians(40), math.radians(15), math.radians(30))
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.75, 0.8, 0.88, 1.0)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.8
    scene.world = world

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = a.samples
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = a.size
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = a.out
    bpy.ops.render.render(write_still=True)
    print(f"RENDERED {a.out}")


main()
