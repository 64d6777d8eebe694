"""Writes bench/scenes/product.glb, a product shot's asset built and exported with Blender,
bench/scenes/product.json, the xi scene that shows it under the bundled sky as product shots are framed,
and bench/scenes/product-sky.json, the same scene with the camera turned to the sky: every camera ray
escapes, which measures what an escaped ray costs.

The asset (Blender's own glTF exporter, tangents on, no camera, no lights, no floor): a drinks can (a
bevelled cylinder) whose label has a base colour texture, a metallic-roughness texture (bare metal bands,
printed panels) and a normal map (ribs), and a ball beside it with its own colour, roughness and normal
textures: the textured, normal-mapped metallic-roughness materials assets bring. The camera looks from the
front and 15 degrees above; the objects fill about a fifth of the frame, so most camera rays leave the scene
for the sky, as in a product shot.

Runs in the Cycles venv (bench/setup-cycles.sh): `bench/.venv-bpy/bin/python bench/make_product_scene.py`."""
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.dont_write_bytecode = True
SCENES = Path(__file__).resolve().parent / "scenes"
N = 256  # texture size


def image(bpy, name, rgb, folder, colorspace):
    """An (N, N, 3) array, rows from the bottom as Blender stores them, saved as a PNG and loaded."""
    img = bpy.data.images.new(name, N, N, alpha=False)
    img.colorspace_settings.name = colorspace
    img.pixels.foreach_set(np.concatenate([rgb, np.ones((N, N, 1))], -1).astype(np.float32).ravel())
    img.filepath_raw = str(Path(folder) / f"{name}.png")
    img.file_format = "PNG"
    img.save()
    return img


def normal_map(height, strength):
    """A tangent-space normal map (glTF's and Blender's convention, +y along +v) of a height field."""
    dv, du = np.gradient(height)
    n = np.stack([-strength * du * N, -strength * dv * N, np.ones_like(height)], -1)
    return 0.5 * n / np.linalg.norm(n, axis=-1, keepdims=True) + 0.5


def material(bpy, name, colour, metallic_roughness, normals, folder):
    """A Principled BSDF of three textures: base colour (sRGB), metallic-roughness (G roughness, B metallic,
    as glTF packs them) and a tangent-space normal map."""
    m = bpy.data.materials.new(name)
    nodes, links = m.node_tree.nodes, m.node_tree.links
    p = nodes["Principled BSDF"]
    p.inputs["IOR"].default_value = 1.5  # glTF's default: no KHR_materials_ior in the file
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image(bpy, f"{name}-colour", colour, folder, "sRGB")
    links.new(tex.outputs["Color"], p.inputs["Base Color"])
    mr = nodes.new("ShaderNodeTexImage")
    mr.image = image(bpy, f"{name}-metallic-roughness", metallic_roughness, folder, "Non-Color")
    split = nodes.new("ShaderNodeSeparateColor")
    links.new(mr.outputs["Color"], split.inputs["Color"])
    links.new(split.outputs["Green"], p.inputs["Roughness"])
    links.new(split.outputs["Blue"], p.inputs["Metallic"])
    nt = nodes.new("ShaderNodeTexImage")
    nt.image = image(bpy, f"{name}-normal", normals, folder, "Non-Color")
    nmap = nodes.new("ShaderNodeNormalMap")
    nmap.space = "TANGENT"
    links.new(nt.outputs["Color"], nmap.inputs["Color"])
    links.new(nmap.outputs["Normal"], p.inputs["Normal"])
    return m


def textures():
    """The label's and the ball's three images each, as (N, N, 3) arrays."""
    u, v = np.meshgrid((np.arange(N) + 0.5) / N, (np.arange(N) + 0.5) / N)
    band = (v < 0.12) | (v > 0.88)                                  # bare metal at the rims
    panel = (np.abs(((u * 4) % 1) - 0.5) < 0.3) & ~band             # four printed panels round the can
    colour = np.where(panel[..., None], [0.75, 0.12, 0.08], [0.9, 0.85, 0.7])
    colour = np.where(band[..., None], [0.8, 0.8, 0.82], colour) * (0.85 + 0.15 * np.sin(40 * np.pi * v))[..., None]
    label_mr = np.stack([np.zeros_like(u), np.where(band, 0.25, np.where(panel, 0.45, 0.3)),
                         np.where(band, 1.0, np.where(panel, 0.0, 0.6))], -1)
    ribs = 0.002 * np.sin(24 * np.pi * v) * ~band
    ball_colour = np.where(((u * 12).astype(int) + (v * 6).astype(int))[..., None] % 2 == 1,
                           [0.2, 0.45, 0.75], [0.95, 0.9, 0.8])
    grain = np.sin(60 * np.pi * u) * np.sin(30 * np.pi * v)
    ball_mr = np.stack([np.zeros_like(u), 0.5 + 0.2 * grain, np.zeros_like(u)], -1)
    return dict(label=(colour, label_mr, normal_map(ribs, 1.0)),
                ball=(ball_colour, ball_mr, normal_map(0.001 * grain, 1.0)))


def build(bpy, folder):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    maps = textures()
    bpy.ops.mesh.primitive_cylinder_add(vertices=96, radius=0.33, depth=1.0, location=(-0.2, 0, 0.5))
    can = bpy.context.object
    bevel = can.modifiers.new("bevel", "BEVEL")
    bevel.width, bevel.segments = 0.04, 6
    can.modifiers.new("subdivision", "SUBSURF").levels = 1
    bpy.ops.object.shade_smooth()
    can.data.materials.append(material(bpy, "label", *maps["label"], folder))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.22, location=(0.42, -0.25, 0.22), segments=64, ring_count=32)
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(material(bpy, "ball", *maps["ball"], folder))


def scene_json():
    """The xi scene: the asset under scenes/sky.hdr (turned 30 degrees), from the front and 15 degrees above
    (Blender's +z up is glTF's +y, its -y, towards the camera, glTF's +z)."""
    centre, distance, elevation = (0.05, 0.5, 0.1), 3.1, math.radians(15)
    eye = [centre[0], centre[1] + distance * math.sin(elevation), centre[2] + distance * math.cos(elevation)]
    return {"camera": {"position": [round(x, 4) for x in eye], "look_at": list(centre), "up": [0, 1, 0], "fov": 40},
            "film": {"width": 512, "height": 512},
            "render": {"spp": 64, "max_depth": 8},
            "environment": {"file": "../../scenes/sky.hdr", "strength": 1, "rotation": 30},
            "materials": {}, "shapes": [{"type": "asset", "file": "product.glb"}]}


def sky_json():
    """The same scene, the camera turned up and away from the asset: nothing but the sky in view."""
    scene = scene_json()
    scene["camera"]["look_at"] = [scene["camera"]["position"][0], 40.0, -60.0]
    return scene


def main():
    import bpy
    with tempfile.TemporaryDirectory() as tmp:
        build(bpy, tmp)
        glb = SCENES / "product.glb"
        bpy.ops.export_scene.gltf(filepath=str(glb), export_format="GLB", export_cameras=False,
                                  export_lights=False, export_apply=True, export_yup=True, export_tangents=True)
    (SCENES / "product.json").write_text(json.dumps(scene_json(), indent=1) + "\n")
    (SCENES / "product-sky.json").write_text(json.dumps(sky_json(), indent=1) + "\n")
    print(f"wrote {glb}, {SCENES / 'product.json'} and {SCENES / 'product-sky.json'}")


if __name__ == "__main__":
    main()
