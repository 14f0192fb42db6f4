"""Renders a .glb in Blender, headless, from given pinhole cameras: what a user sees who imports our glTF export.

Runs inside Blender (``bpy``), not in the package's Python:

    blender -b --factory-startup --python scripts/gltf_blender_render.py -- scene.glb cameras.json OUT_PREFIX

``cameras.json`` is ``{"c2w": [N x 4 x 4], "fx": [...], "fy": [...], "cx": [...], "cy": [...], "width": W,
"height": H, "background": [r, g, b]}`` in Blender's world frame (Z up) and OpenGL camera convention
(``render/cameras.py``); for a +z-up capture that is the bundle's own frame, since the export turns +z onto glTF's
+Y and Blender's importer turns +Y back onto +Z;
the background colour is as displayed (sRGB, 0..1). Writes ``OUT_PREFIX<i>.png`` (8-bit RGB) per camera and
``OUT_PREFIXobjects.json``: {mesh object name: its world translation in Blender's frame}.

The importer (Blender's own io_scene_gltf2) turns glTF's +Y up into Blender's +Z up; the cameras are placed as
given, not turned. Cycles renders (no OpenGL context needed) with the Standard view transform (Blender's default,
Filmic, would tone-map the texture), no dither, and a pixel filter 0.01 pixels wide: each pixel is the scene at
its centre, as a rasterizer samples it. The importer makes KHR_materials_unlit an emission seen by camera rays,
so a pixel shows the base-colour texture as stored.
"""

import json
import sys

import bpy
from mathutils import Matrix

def srgb_to_linear(c: float) -> float:
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def main(glb: str, cameras_json: str, prefix: str) -> None:
    import warnings

    import numpy as np

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if not hasattr(np, "bool"):      # Debian 12's Blender 3.4 importer calls np.bool, gone since numpy 1.24
            np.bool = bool
    cams = json.loads(open(cameras_json).read())
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=glb)
    scene = bpy.context.scene
    # where the importer placed each mesh (the glTF nodes' transforms, in Blender's Z-up frame)
    placed = {o.name: list(o.matrix_world.translation) for o in scene.objects if o.type == "MESH"}
    open(prefix + "objects.json", "w").write(json.dumps(placed))
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 4
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.filter_width = 0.01
    scene.render.dither_intensity = 0.0
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"
    scene.render.resolution_x, scene.render.resolution_y = int(cams["width"]), int(cams["height"])
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"

    world = bpy.data.worlds.new("background")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*[srgb_to_linear(c) for c in cams["background"]], 1.0)
    bg.inputs["Strength"].default_value = 1.0
    scene.world = world

    data = bpy.data.cameras.new("camera")
    camera = bpy.data.objects.new("camera", data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    w, h = int(cams["width"]), int(cams["height"])
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    data.clip_start, data.clip_end = 1e-3, 1e5
    for i, c2w in enumerate(cams["c2w"]):
        fx, fy, cx, cy = (float(cams[k][i]) for k in ("fx", "fy", "cx", "cy"))
        if abs(fx - fy) > 1e-3 * fx:
            raise SystemExit(f"camera {i}: fx {fx} != fy {fy}; set the pixel aspect for non-square pixels")
        data.lens = fx * data.sensor_width / w
        data.shift_x = -(cx - 0.5 * w) / max(w, h)             # shifts are in units of the larger side
        data.shift_y = (cy - 0.5 * h) / max(w, h)
        camera.matrix_world = Matrix(c2w)
        scene.render.filepath = f"{prefix}{i}.png"
        bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    if len(args) != 3:
        raise SystemExit("usage: blender -b --python scripts/gltf_blender_render.py -- scene.glb cameras.json OUT")
    main(*args)
