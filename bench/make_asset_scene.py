"""Writes bench/scenes/textured.glb, a small textured glTF asset built and exported with Blender, and
bench/scenes/textured.json, the xi scene that places it under the bundled sky with a camera.

The asset (Blender's own glTF exporter, no camera, no lights): a tiled floor, Blender's Suzanne (subdivided
once, smooth) with a striped texture, a checkered sphere and a small gold sphere (metallic 1, roughness
0.25). Materials are glTF metallic-roughness with a base colour texture at most, all with repeat wrapping,
so that xi, Cycles (through Blender's glTF importer) and Mitsuba (through `xi export`) read the same file.

Runs in the Cycles venv (bench/setup-cycles.sh): `bench/.venv-bpy/bin/python bench/make_asset_scene.py`."""
import json
import math
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import make_material_scene as mk  # noqa: E402

SCENES = HERE / "scenes"


def stripes(n=128):
    """Diagonal bands of four colours, so that the texture's orientation on Suzanne shows."""
    colours = [(200, 60, 40), (230, 180, 60), (60, 120, 190), (235, 230, 220)]
    return [[colours[((x + y) * 8 // n) % 4] for x in range(n)] for y in range(n)]


def checker(n=128, cells=8):
    return [[(220, 220, 210) if (x * cells // n + y * cells // n) % 2 else (40, 90, 60) for x in range(n)]
            for y in range(n)]


def material(bpy, name, base_color, roughness, metallic=0.0, image=None):
    m = bpy.data.materials.new(name)
    nodes, links = m.node_tree.nodes, m.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*base_color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["IOR"].default_value = 1.5  # glTF's default: no KHR_materials_ior in the file
    if image is not None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = bpy.data.images.load(str(image))
        tex.extension = "REPEAT"
        links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return m


def build(bpy, images):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ops = bpy.ops.mesh
    ops.primitive_plane_add(size=6, location=(0, 0, 0))
    floor = bpy.context.object
    for loop in floor.data.uv_layers.active.data:  # the tiles repeat three times across
        loop.uv = (loop.uv[0] * 3, loop.uv[1] * 3)
    floor.data.materials.append(material(bpy, "tiles", (1, 1, 1), 0.8, image=images["tiles"]))

    ops.primitive_monkey_add(size=1.4, location=(-0.85, 0.1, 0.75), rotation=(math.radians(-10), 0, math.radians(20)))
    monkey = bpy.context.object
    monkey.modifiers.new("subdivision", "SUBSURF").levels = 1
    bpy.ops.object.shade_smooth()
    monkey.data.materials.append(material(bpy, "stripes", (1, 1, 1), 0.35, image=images["stripes"]))

    ops.primitive_uv_sphere_add(radius=0.6, location=(0.95, 0.35, 0.6), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(material(bpy, "checker", (1, 1, 1), 0.6, image=images["checker"]))

    ops.primitive_uv_sphere_add(radius=0.35, location=(0.15, -0.95, 0.35), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(material(bpy, "gold", (1.0, 0.78, 0.34), 0.25, metallic=1.0))


def scene_json():
    """The xi scene: the asset under scenes/sky.hdr (turned 30 degrees), seen from the front and above.
    Blender's +z up becomes glTF's +y, its -y (towards the camera here) glTF's +z."""
    return {"camera": {"position": [0.0, 2.3, 4.6], "look_at": [0.0, 0.45, 0.0], "up": [0, 1, 0], "fov": 38},
            "film": {"width": 512, "height": 512},
            "render": {"spp": 64, "max_depth": 8},
            "environment": {"file": "../../scenes/sky.hdr", "strength": 1, "rotation": 30},
            "materials": {}, "shapes": [{"type": "asset", "file": "textured.glb"}]}


def main():
    import bpy
    with tempfile.TemporaryDirectory() as tmp:
        images = {}
        for name, pixels in (("tiles", mk.tiles()), ("stripes", stripes()), ("checker", checker())):
            images[name] = Path(tmp) / f"{name}.png"
            mk.write_png(images[name], len(pixels[0]), len(pixels), pixels)
        build(bpy, images)
        glb = SCENES / "textured.glb"
        bpy.ops.export_scene.gltf(filepath=str(glb), export_format="GLB", export_cameras=False,
                                  export_lights=False, export_apply=True, export_yup=True)
    (SCENES / "textured.json").write_text(json.dumps(scene_json(), indent=1) + "\n")
    print(f"wrote {glb} and {SCENES / 'textured.json'}")


if __name__ == "__main__":
    main()
