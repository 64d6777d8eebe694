#!/usr/bin/python3
"""xi against Blender's Cycles on glTF files written by Blender itself, as artists' files are: per material,
the ratio of the two renderers' mean radiance where that material is seen.

Files. Blender (PyPI's bpy in bench/.venv-bpy, bench/setup-cycles.sh) builds one .glb per group of Principled
BSDF materials: a grid of UV spheres, one material each, and a camera, with no floor (each sphere is lit by
the map and little else, so one material's error does not spread into the others' regions), written by its
own exporter (bpy.ops.export_scene.gltf, tangents on), each file from a fresh Blender process. Groups:
(dielectric) grey and red bases at roughness 0.05, 0.3, 0.6, 1; (metal) gold and silver at the same
roughnesses; (textured) a base colour image and a tangent-space normal map, both made in bpy; (clearcoat)
Coat Weight and Coat Roughness; (sheen) Sheen Weight, Tint and Roughness; (specular) Specular IOR Level and
Specular Tint; (transmission) Transmission Weight 1, with and without a Volume Absorption node on the
material output and the exporter's "glTF Material Output" group giving a thickness (KHR_materials_volume);
(anisotropy) Anisotropic and Anisotropic Rotation, and the same file again as anisotropy-gltf, where Cycles'
Principled BSDFs are given glTF's alphas after the import (Blender's importer passes the extension's strength
as its own Anisotropic, a different mapping); (iridescence) Thin Film Thickness and IOR, which Blender's
exporter does not write nor its importer read: the driver adds KHR_materials_iridescence to the file and gives
Cycles' imported Principled BSDFs their Thin Film inputs back; (alpha) Alpha below 1, written as alphaMode
BLEND (stochastic transparency in both); (emissive) a control where the two models coincide, black
spheres emitting radiance 1, 4 and 10 (KHR_materials_emissive_strength). The extensions each file holds are
read back from its JSON and printed: what the exporter chose to write, not what was asked for. Where Debian's
assimp-testmodels are installed, ClearCoatTest.gltf and BoxTextured.gltf are added, copied with their
materials untouched and a camera node added (from +z and 15 degrees above, as xi frames a file without a
camera, the bounding box's front filling a 40-degree vertical field of view).

Renders. Both renderers read the same file with its own camera: xi through `xi render FILE --env ...`, Cycles
through Blender's glTF importer (bpy.ops.import_scene.gltf), so Cycles renders Blender's own reading of the
file (e.g. its importer turns KHR_materials_volume's attenuation colour and distance into a Volume
Absorption node of that colour and density 1 / distance, not glTF's exponential attenuation). Both are under
the same environment map (--env, turned --env-rotate degrees about +y; Cycles' world as bench/cycles_scene.py
maps xi's rotation) with the same path length (xi's --max-depth K, Cycles' max_bounces K - 1) and
cycles_scene.py's settings (box filter 1 px, no clamping, caustics on). xi renders SPP samples per pixel with
the random sampler and gives each pixel's variance of the mean (its EXR's variance layer); Cycles renders
K = --cycles-runs images of SPP / K with seeds 1..K, its pixel variance being their sample variance / K.
Both images are linear EXR.

Regions. Cycles' material index pass (each imported material's pass_index set to 1, 2, ... by name; 0 is the
background; its alpha threshold 0, so a transparent surface counts) gives, per material, the pixels whose first
hit is that material; a pixel counts if every pixel
within --erode pixels (a square) has the same index, which leaves out the edges, where the two renderers'
pixel footprints differ most. The background (the map seen directly) is a region too: it checks that the
camera and the map's orientation agree. Per region and channel: the ratio of the means, xi / Cycles, its
standard error (from both variances, pixels independent) and z = (mean xi - mean Cycles) / sqrt(var xi + var
Cycles) of the region means. A region passes if every channel's ratio is within --tolerance (2%) of 1.
Regions with fewer than --min-pixels pixels are listed without figures. Block z-tests: the image is cut into
--block x --block tiles; each tile at least half inside a region is a block of it, and each block and
channel gets the same z of its own means. Where the models coincide and both renderers are unbiased, each z
is close to a standard normal: a block fails at |z| > 3.29 (two-sided significance 0.001), so about one
test in a thousand fails by chance; the table gives the failed tests against all of the region's (blocks x
3 channels) and the mean z^2 (about 1 where the images differ only by noise). A region whose ratios pass
but whose blocks fail differs in where it is bright, not in how bright it is on the whole.

Output: the table on stdout, and bench/out/validate_cycles/ (--out): validate_cycles.json (every figure, the
extensions, the cameras and xi's warnings per file), the .glb files, both renderers' EXRs and PNGs. The exit
status is 0 when everything rendered, whatever the ratios (this is a report); errors exit non-zero, and a
file xi fails to render is reported in the table, the run going on and then exiting 1.

  bash bench/setup-cycles.sh                      # once: bench/.venv-bpy with bpy 5.0.1
  bench/validate_cycles.py                        # 5-7 minutes on 2 cores, most of it Cycles
  bench/validate_cycles.py --files dielectric,metal --resolution 128x128 --spp 64
  XI_KERNEL_DIR=/path/kernels bench/validate_cycles.py --xi /path/xi   # another build; xi gets this environment

The script runs on Debian's python3 with numpy (or any Python with numpy); the bpy part runs in worker
processes on bench/.venv-bpy/bin/python (this same file with --worker LOG), whose messages go to
bench/out/validate_cycles/blender.log."""
import json
import math
import os
import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import common as c  # noqa: E402

try:
    import numpy as np
    import exr  # noqa: E402  (needs numpy)
except ImportError:
    sys.exit("bench: numpy is missing: scripts/install-deps.sh --bench installs Debian's python3-numpy "
             "(for /usr/bin/python3)")

CYCLES_PYTHON = HERE / ".venv-bpy" / "bin" / "python"
BLENDER_LOG = None  # the workers' messages, in the output folder
SKY = c.ROOT / "scenes" / "sky.hdr"
DEBIAN_MODELS = Path("/usr/share/assimp/models/glTF2")
DEBIAN_FILES = {"ClearCoatTest": DEBIAN_MODELS / "ClearCoat-glTF" / "ClearCoatTest.gltf",
                "BoxTextured": DEBIAN_MODELS / "BoxTextured-glTF" / "BoxTextured.gltf"}

# ---------------------------------------------------------------------------------------------------------
# The groups: per sphere a material name and the Principled BSDF inputs it sets (colours as RGB), plus
# 'texture' / 'normal_map' (images made in bpy) and 'volume' (absorption colour, density and thickness).

ROUGHNESSES = (0.05, 0.3, 0.6, 1.0)
GREY, RED = (0.5, 0.5, 0.5), (0.8, 0.12, 0.04)
GOLD, SILVER = (1.0, 0.766, 0.336), (0.95, 0.93, 0.88)


def _rough(prefix, base, r, **more):
    return (f"{prefix}-r{r:g}", {"Base Color": base, "Roughness": r, **more})


def _coat(name, base, roughness, weight, coat_roughness):
    return (name, {"Base Color": base, "Roughness": roughness, "Coat Weight": weight,
                   "Coat Roughness": coat_roughness})


GROUPS = {
    "dielectric": [_rough("grey", GREY, r) for r in ROUGHNESSES] + [_rough("red", RED, r) for r in ROUGHNESSES],
    "metal": [_rough("gold", GOLD, r, Metallic=1.0) for r in ROUGHNESSES]
             + [_rough("silver", SILVER, r, Metallic=1.0) for r in ROUGHNESSES],
    "textured": [("tex-r0.6", {"Roughness": 0.6, "texture": True}),
                 ("tex-normal-r0.6", {"Roughness": 0.6, "texture": True, "normal_map": 1.0}),
                 ("tex-normal-r0.15", {"Roughness": 0.15, "texture": True, "normal_map": 1.0}),
                 ("normal-metal-r0.3", {"Base Color": SILVER, "Metallic": 1.0, "Roughness": 0.3,
                                        "normal_map": 1.0})],
    "clearcoat": [_coat("coat1-r0.05-on-red", RED, 0.6, 1.0, 0.05),
                  _coat("coat1-r0.3-on-red", RED, 0.6, 1.0, 0.3),
                  _coat("coat0.5-r0.05-on-red", RED, 0.6, 0.5, 0.05),
                  _coat("coat1-r0.05-on-grey", GREY, 1.0, 1.0, 0.05)],
    "sheen": [("sheen-white-r0.3", {"Base Color": (0.05, 0.05, 0.2), "Roughness": 0.8, "Sheen Weight": 1.0,
                                    "Sheen Tint": (1, 1, 1), "Sheen Roughness": 0.3}),
              ("sheen-white-r0.8", {"Base Color": (0.05, 0.05, 0.2), "Roughness": 0.8, "Sheen Weight": 1.0,
                                    "Sheen Tint": (1, 1, 1), "Sheen Roughness": 0.8}),
              ("sheen-orange-r0.5", {"Base Color": (0.05, 0.05, 0.2), "Roughness": 0.8, "Sheen Weight": 1.0,
                                     "Sheen Tint": (1.0, 0.5, 0.1), "Sheen Roughness": 0.5}),
              ("sheen0.5-on-grey", {"Base Color": GREY, "Roughness": 0.8, "Sheen Weight": 0.5,
                                    "Sheen Tint": (1, 1, 1), "Sheen Roughness": 0.5})],
    "specular": [("spec-level0", {"Base Color": GREY, "Roughness": 0.3, "Specular IOR Level": 0.0}),
                 ("spec-level0.25", {"Base Color": GREY, "Roughness": 0.3, "Specular IOR Level": 0.25}),
                 ("spec-level1", {"Base Color": GREY, "Roughness": 0.3, "Specular IOR Level": 1.0}),
                 ("spec-tint-orange", {"Base Color": GREY, "Roughness": 0.3, "Specular Tint": (1.0, 0.5, 0.2)})],
    "transmission": [("glass-r0", {"Roughness": 0.0, "Transmission Weight": 1.0}),
                     ("glass-r0.3", {"Roughness": 0.3, "Transmission Weight": 1.0}),
                     ("glass-volume-r0", {"Roughness": 0.0, "Transmission Weight": 1.0,
                                          "volume": ((0.9, 0.45, 0.2), 2.0)}),
                     ("glass-volume-r0.3", {"Roughness": 0.3, "Transmission Weight": 1.0,
                                            "volume": ((0.9, 0.45, 0.2), 2.0)})],
    "anisotropy": [("aniso0.5-metal-r0.4", {"Base Color": SILVER, "Metallic": 1.0, "Roughness": 0.4,
                                            "Anisotropic": 0.5}),
                   ("aniso0.9-metal-r0.4", {"Base Color": SILVER, "Metallic": 1.0, "Roughness": 0.4,
                                            "Anisotropic": 0.9}),
                   ("aniso0.9-rot0.25-metal", {"Base Color": SILVER, "Metallic": 1.0, "Roughness": 0.4,
                                               "Anisotropic": 0.9, "Anisotropic Rotation": 0.25}),
                   ("aniso0.9-grey-r0.3", {"Base Color": GREY, "Roughness": 0.3, "Anisotropic": 0.9}),
                   ("aniso0.9-rot0.25-grey", {"Base Color": GREY, "Roughness": 0.3, "Anisotropic": 0.9,
                                              "Anisotropic Rotation": 0.25})],
    # Thin Film Thickness (nm) and IOR: Blender's exporter does not write KHR_materials_iridescence (nor does
    # its importer read it), so the driver adds it to the file (add_thin_films) and gives the imported
    # Principled BSDFs their Thin Film inputs back (load): where the two models coincide
    "iridescence": [("film300-grey-r0.2", {"Base Color": GREY, "Roughness": 0.2, "film": (300.0, 1.3)}),
                    ("film500-ior1.8-black-r0.1", {"Base Color": (0.02, 0.02, 0.02), "Roughness": 0.1,
                                                   "film": (500.0, 1.8)}),
                    ("film400-silver-r0.2", {"Base Color": SILVER, "Metallic": 1.0, "Roughness": 0.2,
                                             "film": (400.0, 1.3)}),
                    ("film350-red-r0.3", {"Base Color": RED, "Roughness": 0.3, "film": (350.0, 1.3)})],
    # Alpha below 1 (the exporter's alphaMode BLEND): stochastic transparency in both
    "alpha": [("alpha0.5-black-r0.05", {"Base Color": (0.02, 0.02, 0.02), "Roughness": 0.05, "Alpha": 0.5}),
              ("alpha0.25-red-r0.3", {"Base Color": RED, "Roughness": 0.3, "Alpha": 0.25}),
              ("alpha0.75-grey-r0.6", {"Base Color": GREY, "Roughness": 0.6, "Alpha": 0.75}),
              ("alpha0.5-gold-r0.2", {"Base Color": GOLD, "Metallic": 1.0, "Roughness": 0.2, "Alpha": 0.5})],
    # a control where the two models coincide: emission (black bases, so that little else is seen)
    "emissive": [("emit-white-1", {"Base Color": (0, 0, 0), "Emission Color": (1, 1, 1), "Emission Strength": 1.0}),
                 ("emit-white-4", {"Base Color": (0, 0, 0), "Emission Color": (1, 1, 1), "Emission Strength": 4.0}),
                 ("emit-orange-10", {"Base Color": (0, 0, 0), "Emission Color": (1.0, 0.5, 0.1),
                                     "Emission Strength": 10.0})],
}
# The anisotropy file again, Cycles' Principled BSDFs given glTF's alphas instead of its importer's reading
# (see gltf_anisotropy): where the two models coincide.
GLTF_ANISOTROPY = "anisotropy-gltf"
RADIUS, SPACING = 0.45, 1.05


# ---------------------------------------------------------------------------------------------------------
# The worker: Blender, in bench/.venv-bpy (Blender's frame, +z up; the exporter writes glTF's +y up)

def _principled_material(bpy, name, spec, texdir):
    """A material of one Principled BSDF with SPEC's inputs; images written to TEXDIR for the texture and the
    normal map (the exporter embeds them)."""
    m = bpy.data.materials.new(name)  # (Blender 5: with a Principled BSDF and an output already)
    nodes, links = m.node_tree.nodes, m.node_tree.links
    p, out = nodes["Principled BSDF"], nodes["Material Output"]
    for key, value in spec.items():
        if key in ("texture", "normal_map", "volume", "film"):
            continue
        p.inputs[key].default_value = (*value, 1.0) if isinstance(value, tuple) else value
    n = 256
    u, v = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n)
    if spec.get("Alpha", 1.0) < 1.0:
        m.surface_render_method = "BLENDED"  # what the exporter writes as alphaMode BLEND
    if spec.get("film"):
        p.inputs["Thin Film Thickness"].default_value, p.inputs["Thin Film IOR"].default_value = spec["film"]
    if spec.get("texture"):
        # 8 x 4 checker cells (the UV sphere's u runs round it, v pole to pole), two sRGB colours with a
        # gradient across each cell so that a flip or a filtering difference would show
        checker = ((u * 8).astype(int) + (v * 4).astype(int)) % 2 == 1
        ramp = 0.6 + 0.4 * ((u * 8) % 1)
        rgb = np.where(checker[..., None], [0.85, 0.65, 0.2], [0.15, 0.35, 0.7]) * ramp[..., None]
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = _image(bpy, f"{name}-colour", rgb, texdir, "sRGB")
        links.new(tex.outputs["Color"], p.inputs["Base Color"])
    if spec.get("normal_map"):
        # 8 x 4 bumps, the slopes of sin(16 pi u) sin(8 pi v) scaled, as a tangent-space normal (glTF's and
        # Blender's convention: +y along +v)
        k = 0.35
        dx = k * np.cos(16 * np.pi * u) * np.sin(8 * np.pi * v)
        dy = 0.5 * k * np.sin(16 * np.pi * u) * np.cos(8 * np.pi * v)
        normal = np.stack([-dx, -dy, np.ones_like(u)], -1)
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = _image(bpy, f"{name}-normal", normal * 0.5 + 0.5, texdir, "Non-Color")
        nmap = nodes.new("ShaderNodeNormalMap")
        nmap.space = "TANGENT"
        nmap.inputs["Strength"].default_value = spec["normal_map"]
        links.new(tex.outputs["Color"], nmap.inputs["Color"])
        links.new(nmap.outputs["Normal"], p.inputs["Normal"])
    if spec.get("volume"):
        # what the exporter reads for KHR_materials_volume: the thickness from an input of a node group named
        # "glTF Material Output" (made here as the add-on makes it), the attenuation from a Volume Absorption
        # node on the output's Volume socket (attenuationDistance = 1 / density)
        colour, density = spec["volume"]
        group = bpy.data.node_groups.get("glTF Material Output")
        if group is None:
            group = bpy.data.node_groups.new("glTF Material Output", "ShaderNodeTree")
            group.interface.new_socket("Occlusion", in_out="INPUT", socket_type="NodeSocketFloat")
            group.interface.new_socket("Thickness", in_out="INPUT", socket_type="NodeSocketFloat")
            group.nodes.new("NodeGroupOutput")
            group.nodes.new("NodeGroupInput")
        settings = nodes.new("ShaderNodeGroup")
        settings.node_tree = group
        settings.inputs["Thickness"].default_value = 2 * RADIUS  # the sphere's diameter
        absorption = nodes.new("ShaderNodeVolumeAbsorption")
        absorption.inputs["Color"].default_value = (*colour, 1.0)
        absorption.inputs["Density"].default_value = density
        links.new(absorption.outputs["Volume"], out.inputs["Volume"])
    return m


def _image(bpy, name, rgb, texdir, colorspace):
    """An RGB array (rows from the bottom, as Blender stores them; values as stored, sRGB-encoded for colour)
    saved as a PNG and loaded as a Blender image."""
    h, w, _ = rgb.shape
    img = bpy.data.images.new(name, w, h, alpha=False)
    img.colorspace_settings.name = colorspace
    img.pixels.foreach_set(np.concatenate([rgb, np.ones((h, w, 1))], -1).astype(np.float32).ravel())
    Path(texdir).mkdir(parents=True, exist_ok=True)
    img.filepath_raw = str(Path(texdir) / f"{name}.png")
    img.file_format = "PNG"
    img.save()
    return img


def build(bpy, req):
    """Builds group REQ['group'] and writes it as a .glb to REQ['out']."""
    from mathutils import Vector
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = req["width"], req["height"]  # the camera's aspect
    texdir = Path(req["out"]).parent / f"{Path(req['out']).stem}-textures"
    spheres = GROUPS[req["group"]]
    columns = 2 if len(spheres) <= 4 else 4  # 2 x 2 or 4 x 2 spheres
    rows = math.ceil(len(spheres) / columns)
    for i, (name, spec) in enumerate(spheres):
        row, col = divmod(i, columns)
        x = (col - (columns - 1) / 2) * SPACING
        z = RADIUS + 0.1 + (rows - 1 - row) * SPACING
        bpy.ops.mesh.primitive_uv_sphere_add(radius=RADIUS, location=(x, 0, z), segments=96, ring_count=48)
        obj = bpy.context.object
        obj.name = name
        bpy.ops.object.shade_smooth()
        obj.data.materials.append(_principled_material(bpy, name, spec, texdir))
    # the camera, in front (-y in Blender, +z in glTF) and a little above the grid's centre, looking at it
    centre = Vector((0, 0, RADIUS + 0.1 + (rows - 1) * SPACING / 2))
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "VERTICAL"
    half = max(columns * SPACING / 2 * req["height"] / req["width"], rows * SPACING / 2) + 0.2
    eye = centre + Vector((0, -7.0, 0.8))
    data.angle_y = 2 * math.atan(half / (centre - eye).length)
    cam = bpy.data.objects.new("camera", data)
    cam.location = eye
    cam.rotation_euler = (centre - eye).to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(cam)
    scene.camera = cam
    bpy.ops.export_scene.gltf(filepath=req["out"], export_format="GLB", export_cameras=True, export_tangents=True,
                              export_lights=False, export_yup=True)
    return dict(materials=[s[0] for s in spheres])


def bounds(bpy, req):
    """The bounding box of the meshes of REQ['file'] in glTF's frame, through Blender's importer."""
    from mathutils import Vector
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=req["file"])
    pts = [o.matrix_world @ Vector(corner) for o in bpy.data.objects if o.type == "MESH" for corner in o.bound_box]
    p = np.array([(q.x, q.z, -q.y) for q in pts])  # Blender (x, y, z) -> glTF (x, z, -y)
    return dict(min=p.min(axis=0).tolist(), max=p.max(axis=0).tolist())


def gltf_anisotropy(bpy):
    """Blender's importer passes KHR_materials_anisotropy's strength s as the Principled BSDF's Anisotropic A,
    whose alphas are r^2 / a and r^2 a, a = sqrt(1 - 0.9 A); glTF's are r^2 + (1 - r^2) s^2 along the
    direction and r^2 across it. Sets each Principled's Roughness and Anisotropic to give glTF's (possible
    where the ratio of the two alphas is at least 0.1)."""
    for m in bpy.data.materials:
        for node in (m.node_tree.nodes if m.node_tree else []):
            if node.type != "BSDF_PRINCIPLED" or node.inputs["Anisotropic"].default_value <= 0.0:
                continue
            s, r = node.inputs["Anisotropic"].default_value, node.inputs["Roughness"].default_value
            along, across = r * r + (1.0 - r * r) * s * s, max(r * r, 1e-4)
            node.inputs["Roughness"].default_value = (along * across) ** 0.25
            node.inputs["Anisotropic"].default_value = min((1.0 - across / along) / 0.9, 1.0)


def load(bpy, cs, req):
    """Imports REQ['file'] as Cycles' scene: the file's camera, the environment, the material index pass (and,
    with REQ['gltf_anisotropy'], glTF's anisotropic alphas; REQ['thin_films'], {material: (thickness, ior)},
    the Principled BSDFs' Thin Film inputs)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=req["file"])
    if req.get("gltf_anisotropy"):
        gltf_anisotropy(bpy)
    for m in bpy.data.materials:
        film = req.get("thin_films", {}).get(m.name)
        for node in (m.node_tree.nodes if film and m.node_tree else []):
            if node.type == "BSDF_PRINCIPLED":
                node.inputs["Thin Film Thickness"].default_value, node.inputs["Thin Film IOR"].default_value = film
    scene = cs.settings(bpy, req["width"], req["height"], req["max_depth"])
    cameras = [o for o in bpy.data.objects if o.type == "CAMERA"]
    if not cameras:
        raise ValueError(f"{req['file']} has no camera")
    scene.camera = cameras[0]  # xi's choice too: the first perspective camera
    cs.world(bpy, scene, {"environment": {"file": req["env"], "strength": 1.0, "rotation": req["env_rotate"]}})
    scene.view_layers[0].use_pass_material_index = True
    scene.view_layers[0].pass_alpha_threshold = 0.0  # the first surface hit, however transparent
    materials = {}
    for k, m in enumerate(sorted(bpy.data.materials, key=lambda m: m.name), start=1):
        m.pass_index = k
        materials[m.name] = k
    cam = cameras[0].data
    return dict(materials=materials, camera=dict(name=cameras[0].name, angle_y=cam.angle_y, sensor_fit=cam.sensor_fit))


def worker(log_file):
    """Answers one JSON line per request on stdin: hello, build, bounds, load, render. Blender's messages (and
    Cycles' progress) go to LOG_FILE, not into the replies nor onto the terminal."""
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    fd = os.open(log_file, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    import bpy
    import cycles_scene as cs
    for line in sys.stdin:
        req = json.loads(line)
        cmd = req["cmd"]
        try:
            if cmd == "hello":
                res = dict(version=bpy.app.version_string)
            elif cmd == "build":
                res = build(bpy, req)
            elif cmd == "bounds":
                res = bounds(bpy, req)
            elif cmd == "load":
                res = load(bpy, cs, req)
            elif cmd == "render":
                res = dict(seconds=cs.render(bpy, req["spp"], req["seed"], req["out"]))
            else:
                raise ValueError(f"unknown request {cmd}")
        except Exception as e:  # the driver exits with it
            import traceback
            traceback.print_exc()
            res = dict(error=f"{cmd}: {type(e).__name__}: {e}")
        reply.write(json.dumps(res) + "\n")


# ---------------------------------------------------------------------------------------------------------
# The driver

def log(message):
    print(message, file=sys.stderr, flush=True)


def ask(w, **req):
    r = w.ask(**req)
    if "error" in r:
        sys.exit(f"bench: the Cycles worker failed: {r['error']} (Blender's messages: {BLENDER_LOG})")
    return r


def gltf_json(path):
    """The JSON of a .gltf, or of a .glb's first chunk."""
    data = Path(path).read_bytes()
    if data[:4] != b"glTF":
        return json.loads(data)
    length, kind = struct.unpack_from("<I4s", data, 12)
    if kind != b"JSON":
        raise ValueError(f"{path}: the first chunk is not JSON")
    return json.loads(data[20:20 + length])


def add_thin_films(path, group):
    """Writes KHR_materials_iridescence into the .glb PATH for GROUP's spheres with a film (factor 1, the
    film's ior and thickness, no textures); returns {material: (thickness, ior)}."""
    films = {name: spec["film"] for name, spec in GROUPS[group] if "film" in spec}
    if not films:
        return films
    data = Path(path).read_bytes()
    doc = gltf_json(path)
    length = struct.unpack_from("<I", data, 12)[0]
    for m in doc.get("materials", []):
        if m.get("name") in films:
            thickness, ior = films[m["name"]]
            m.setdefault("extensions", {})["KHR_materials_iridescence"] = {
                "iridescenceFactor": 1.0, "iridescenceIor": ior, "iridescenceThicknessMaximum": thickness}
    doc.setdefault("extensionsUsed", []).append("KHR_materials_iridescence")
    chunk = json.dumps(doc, separators=(",", ":")).encode()
    chunk += b" " * (-len(chunk) % 4)  # chunks are 4-byte aligned, JSON padded with spaces
    rest = data[20 + length:]
    Path(path).write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(chunk) + len(rest))
                           + struct.pack("<I4s", len(chunk), b"JSON") + chunk + rest)
    return films


def extensions(doc):
    """The file's extensionsUsed and, per material name, the extensions it carries with their values."""
    per_material = {m.get("name", f"material {i}"): m.get("extensions", {})
                    for i, m in enumerate(doc.get("materials", []))}
    return doc.get("extensionsUsed", []), per_material


def debian_copy(name, src, dest, box, aspect):
    """SRC's folder copied into DEST with SRC's glTF given a camera node: BOX seen from +z and 15 degrees above
    (as xi frames a file without a camera), its front filling a 40-degree vertical field of view."""
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(src.parent, dest)
    doc = json.loads(src.read_text())
    lo, hi = (list(map(float, box[k])) for k in ("min", "max"))
    centre = [(a + b) / 2 for a, b in zip(lo, hi)]
    half = [(b - a) / 2 for a, b in zip(lo, hi)]
    fov, pitch = math.radians(40), math.radians(15)
    dist = half[2] + 1.25 * max(half[0] / aspect, half[1]) / math.tan(fov / 2)
    eye = [centre[0], centre[1] + dist * math.sin(pitch), centre[2] + dist * math.cos(pitch)]
    doc.setdefault("cameras", []).append({"type": "perspective", "perspective": {
        "yfov": fov, "aspectRatio": aspect, "znear": dist / 1000, "zfar": dist * 100}})
    # a glTF camera looks along its -z: turned down by the pitch about +x
    doc["nodes"].append({"name": "validate-camera", "camera": len(doc["cameras"]) - 1, "translation": eye,
                         "rotation": [-math.sin(pitch / 2), 0.0, 0.0, math.cos(pitch / 2)]})
    doc["scenes"][doc.get("scene", 0)]["nodes"].append(len(doc["nodes"]) - 1)
    out = dest / f"{name}.gltf"
    (dest / src.name).unlink()
    out.write_text(json.dumps(doc, indent=1))
    return out


def erode(mask, r):
    """MASK where all pixels within R (a square) are set too; pixels near the border are left out."""
    if r <= 0:
        return mask
    h, w = mask.shape
    out = np.zeros_like(mask)
    inner = np.ones((h - 2 * r, w - 2 * r), bool)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            inner &= mask[r + dy:h - r + dy, r + dx:w - r + dx]
    out[r:h - r, r:w - r] = inner
    return out


BLOCK_Z = 3.29  # two-sided significance 0.001


def block_tests(a, mask, xi_mean, xi_var, cy_mean, cy_var):
    """The region MASK's block z-tests: (blocks, failed tests, mean z^2) over its blocks and channels."""
    b, (h, w) = a.block, mask.shape
    zs = []
    for y in range(0, h - b + 1, b):
        for x in range(0, w - b + 1, b):
            m = mask[y:y + b, x:x + b]
            n = int(m.sum())
            if 2 * n < b * b:
                continue
            tile = (slice(y, y + b), slice(x, x + b))
            mx, mc = xi_mean[tile][m].mean(axis=0), cy_mean[tile][m].mean(axis=0)
            vx, vc = xi_var[tile][m].sum(axis=0) / n ** 2, cy_var[tile][m].sum(axis=0) / n ** 2
            zs.append((mx - mc) / np.sqrt(np.maximum(vx + vc, 1e-300)))
    if not zs:
        return 0, 0, float("nan")
    zs = np.array(zs)
    return len(zs), int((np.abs(zs) > BLOCK_Z).sum()), float((zs ** 2).mean())


def regions(a, index, materials, xi_mean, xi_var, cy_mean, cy_var):
    """Per material (and the background) the region's figures: pixels, ratio, its standard error, z, and its
    block z-tests."""
    out = []
    for name, k in [("(background)", 0)] + sorted(materials.items(), key=lambda kv: kv[1]):
        mask = erode(index == k, a.erode)
        n = int(mask.sum())
        row = dict(material=name, index=k, pixels=n)
        if n >= a.min_pixels:
            mx, mc = xi_mean[mask].mean(axis=0), cy_mean[mask].mean(axis=0)
            vx, vc = xi_var[mask].sum(axis=0) / n ** 2, cy_var[mask].sum(axis=0) / n ** 2  # of the region means
            ratio = np.where(mc > 0, mx / np.where(mc > 0, mc, 1), np.nan)
            rel_se = np.sqrt(vx / np.maximum(mx, 1e-30) ** 2 + vc / np.maximum(mc, 1e-30) ** 2)
            z = (mx - mc) / np.sqrt(np.maximum(vx + vc, 1e-300))
            blocks, block_failed, block_z2 = block_tests(a, mask, xi_mean, xi_var, cy_mean, cy_var)
            row.update(xi=mx.tolist(), cycles=mc.tolist(), ratio=ratio.tolist(), ratio_se=(ratio * rel_se).tolist(),
                       z=z.tolist(), passed=bool(np.all(np.abs(ratio - 1) <= a.tolerance)), blocks=blocks,
                       block_failed=block_failed, block_mean_z2=block_z2)
        out.append(row)
    return out


def render_xi(a, xi, path, out):
    """xi's render of PATH: (mean, variance of the mean, warnings, its camera line, seconds of the whole
    command), or None and what went wrong where xi fails."""
    cmd = [str(xi), "render", str(path), "-o", str(out), "--spp", str(a.spp), "--seed", "1", "--sampler", "random",
           "--resolution", a.resolution, "--max-depth", str(a.max_depth), "--env", str(a.env),
           "--env-rotate", str(a.env_rotate)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)  # inherits the environment (XI_KERNEL_DIR)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        status = f"signal {-proc.returncode}" if proc.returncode < 0 else f"exit status {proc.returncode}"
        log(f"bench: xi failed ({status}): {' '.join(cmd)}\n{proc.stdout}{proc.stderr}")
        return None, f"xi failed ({status})"
    warnings = [line.removeprefix("xi: warning: ") for line in proc.stderr.splitlines() if "warning" in line]
    camera = next((line for line in proc.stdout.splitlines() if line.startswith("camera ")), "")
    channels, _ = exr.read(out)
    mean = np.stack([channels[ch] for ch in "RGB"], -1)
    var = np.stack([channels[f"variance.{ch}"] for ch in "RGB"], -1)
    return (mean, var, warnings, camera, seconds), None


def render_cycles(a, w, base):
    """Cycles' K renders of SPP / K: (mean, variance of the mean, material index, seconds)."""
    k, images, seconds = a.cycles_runs, [], 0.0
    for seed in range(1, k + 1):
        out = base.with_name(f"{base.stem}-seed{seed}.exr")
        seconds += ask(w, cmd="render", spp=a.spp // k, seed=seed, out=str(out))["seconds"]
        channels, _ = exr.read(out)
        images.append(np.stack([channels[f"ViewLayer.Combined.{ch}"] for ch in "RGB"], -1))
        index = np.rint(channels["ViewLayer.Material Index.X"]).astype(int)  # one sample's: the same in every run
        out.unlink()
    images = np.stack(images)
    return images.mean(0), images.var(0, ddof=1) / k, index, seconds


def fmt_ratio(r):
    return " ".join("-" if r is None or math.isnan(v) else f"{v:.3f}" for v in r)


def main():
    p = c.parser(__doc__)
    p.add_argument("--files", type=c.str_list, default=list(GROUPS) + [GLTF_ANISOTROPY] + list(DEBIAN_FILES),
                   help="groups built in Blender and Debian's files, comma-separated")
    p.add_argument("--resolution", default="256x256")
    p.add_argument("--spp", type=int, default=256, help="xi's spp; Cycles' in all its runs together")
    p.add_argument("--cycles-runs", type=int, default=4, help="K: Cycles renders of SPP/K each, for its variance")
    p.add_argument("--max-depth", type=int, default=8, help="xi's --max-depth; Cycles' max_bounces is one less")
    p.add_argument("--env", default=str(SKY), help="the environment map of both renderers")
    p.add_argument("--env-rotate", type=float, default=60.0, help="its rotation about +y, degrees (xi's --env-rotate)")
    p.add_argument("--erode", type=int, default=2, help="pixels left out at a region's edge")
    p.add_argument("--min-pixels", type=int, default=50, help="smaller regions are listed without figures")
    p.add_argument("--tolerance", type=float, default=0.02, help="a ratio passes within 1 +- this")
    p.add_argument("--block", type=int, default=8, help="the block z-tests' tile size in pixels")
    p.add_argument("--worker-timeout", type=float, default=900, help="seconds a Cycles request may take")
    a = p.parse_args()
    unknown = [f for f in a.files if f not in GROUPS and f != GLTF_ANISOTROPY and f not in DEBIAN_FILES]
    if unknown:
        p.error(f"unknown files {', '.join(unknown)} (known: {', '.join(list(GROUPS) + [GLTF_ANISOTROPY] + list(DEBIAN_FILES))})")
    if a.spp % a.cycles_runs or a.cycles_runs < 2:
        p.error("--spp must be a multiple of --cycles-runs, which must be 2 at least")
    if not CYCLES_PYTHON.exists():
        sys.exit("bench: no bench/.venv-bpy: run bash bench/setup-cycles.sh")
    from time_to_error import Worker
    xi = c.find_xi(a.xi)
    width, height = c.parse_resolution(a.resolution)
    d = Path(a.out).resolve() / "validate_cycles"
    d.mkdir(parents=True, exist_ok=True)
    t_start = time.monotonic()

    global BLENDER_LOG
    BLENDER_LOG = d / "blender.log"
    BLENDER_LOG.unlink(missing_ok=True)
    start = lambda: Worker("Cycles", [CYCLES_PYTHON, Path(__file__).resolve(), "--worker", BLENDER_LOG],
                           a.worker_timeout)
    w = start()
    blender = ask(w, cmd="hello")["version"]
    xi_version = subprocess.run([str(xi), "--version"], capture_output=True, text=True).stdout.strip()
    log(f"{xi_version} ({xi}; XI_KERNEL_DIR={os.environ.get('XI_KERNEL_DIR', 'unset')}); Blender {blender} "
        f"(its messages: {c.shown(BLENDER_LOG)})")

    files = []
    for name in a.files:
        if name in GROUPS or name == GLTF_ANISOTROPY:
            path = d / f"{name}.glb"
            # each file from a fresh Blender: its exporter's caches outlive a scene, and a file written after
            # others may share index accessors between meshes that one written alone does not
            builder = start()
            ask(builder, cmd="build", group="anisotropy" if name == GLTF_ANISOTROPY else name, out=str(path),
                width=width, height=height)
            builder.close()
            files.append((name, path, "Blender " + blender.split()[0], add_thin_films(path, name) if name in GROUPS else {}))
        elif DEBIAN_FILES[name].exists():
            box = ask(w, cmd="bounds", file=str(DEBIAN_FILES[name]))
            files.append((name, debian_copy(name, DEBIAN_FILES[name], d / name, box, width / height),
                          f"Debian {DEBIAN_FILES[name]}", {}))
        else:
            log(f"{name}: {DEBIAN_FILES[name]} is not installed (Debian's assimp-testmodels): left out")

    results = []
    for name, path, origin, thin_films in files:
        used, per_material = extensions(gltf_json(path))
        log(f"{name}: {origin}; extensionsUsed: {', '.join(used) or 'none'}")
        for m, ext in per_material.items():
            if ext:
                log(f"  {m}: " + "; ".join(f"{e} {json.dumps(v, separators=(',', ':'))}" for e, v in ext.items()))
        xi_out, failure = render_xi(a, xi, path, d / f"{name}-xi.exr")
        if failure:
            results.append(dict(file=name, path=str(path), origin=origin, extensions_used=used,
                                material_extensions=per_material, xi_warnings=[], failure=failure, regions=[]))
            continue
        xi_mean, xi_var, warnings, xi_camera, xi_seconds = xi_out
        for line in [xi_camera] + warnings:
            log(f"  xi: {line}")
        loaded = ask(w, cmd="load", file=str(path), width=width, height=height, max_depth=a.max_depth,
                     env=str(a.env), env_rotate=a.env_rotate, gltf_anisotropy=name == GLTF_ANISOTROPY,
                     thin_films=thin_films)
        cy_mean, cy_var, index, cy_seconds = render_cycles(a, w, d / f"{name}-cycles.exr")
        exr.write(d / f"{name}-cycles.exr", cy_mean, dict(spp=a.spp, renderer="cycles"))
        subprocess.run([str(xi), "tonemap", str(d / f"{name}-cycles.exr"), str(d / f"{name}-cycles.png"),
                        "--view", "neutral"], capture_output=True)
        rows = regions(a, index, loaded["materials"], xi_mean, xi_var, cy_mean, cy_var)
        cam = loaded["camera"]
        log(f"  Cycles: camera '{cam['name']}', vertical fov {math.degrees(cam['angle_y']):.2f} degrees")
        log(f"  xi {xi_seconds:.1f} s (the whole command), Cycles {cy_seconds:.1f} s ({a.cycles_runs} renders)")
        results.append(dict(file=name, path=str(path), origin=origin, extensions_used=used,
                            material_extensions=per_material, xi_warnings=warnings, xi_camera=xi_camera,
                            cycles_camera=loaded["camera"],
                            xi_seconds=xi_seconds, cycles_seconds=cy_seconds, regions=rows))
    w.close()
    runtime = time.monotonic() - t_start

    print("\nExtensions in each file (its extensionsUsed) and xi's warnings:")
    for r in results:
        print(f"  {r['file']} ({r['origin']}): {', '.join(r['extensions_used']) or 'none'}"
              + "".join(f"\n    xi: {line}" for line in r["xi_warnings"]))
    print(f"\nxi / Cycles: {a.resolution}, {a.spp} spp each (Cycles {a.cycles_runs} x {a.spp // a.cycles_runs}), "
          f"max depth {a.max_depth}, {Path(a.env).name} turned {a.env_rotate:g} degrees; regions eroded by {a.erode} "
          f"px; pass: every channel within {a.tolerance:.0%}")
    table = []
    for r in results:
        if "failure" in r:
            table.append([r["file"], "(all)", "-", "-", "-", "-", "-", "-", r["failure"]])
        for g in r["regions"]:
            if "ratio" not in g:
                table.append([r["file"], g["material"], g["pixels"], "-", "-", "-", "-", "-", "n/a"])
                continue
            table.append([r["file"], g["material"], g["pixels"], fmt_ratio(g["ratio"]),
                          f"{max(g['ratio_se']):.3f}", f"{max(abs(z) for z in g['z']):.1f}",
                          f"{g['block_failed']}/{3 * g['blocks']}", f"{g['block_mean_z2']:.1f}",
                          "PASS" if g["passed"] else "FAIL"])
    c.print_table(["file", "material", "pixels", "xi/Cycles R G B", "± (1 se)", "max |z|", "blocks |z|>3.29",
                   "mean z^2", "result"], table)
    judged = [g for r in results for g in r["regions"] if "passed" in g]
    print(f"{sum(g['passed'] for g in judged)} of {len(judged)} regions within {a.tolerance:.0%}; "
          f"n/a: fewer than {a.min_pixels} pixels after erosion. ± is the ratio's standard error from both "
          f"renderers' noise; z compares the region means; blocks: {a.block}x{a.block} px tiles, failed z-tests at "
          f"significance 0.001 of all (blocks x 3), and their mean z^2 (1: noise alone). {runtime:.0f} s in all.")
    summary = dict(xi=xi_version, xi_program=str(xi), xi_kernel_dir=os.environ.get("XI_KERNEL_DIR"), blender=blender,
                   resolution=a.resolution, spp=a.spp, cycles_runs=a.cycles_runs, max_depth=a.max_depth,
                   env=str(a.env), env_rotate=a.env_rotate, erode=a.erode, tolerance=a.tolerance, block=a.block,
                   runtime_seconds=runtime, files=results)
    (d / "validate_cycles.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(f"wrote {d / 'validate_cycles.json'}")
    failed = [r["file"] for r in results if "failure" in r]
    if failed:
        print(f"bench: xi failed on {', '.join(failed)} (its output is in the log above)", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--worker"]:
        worker(sys.argv[2])
    else:
        sys.exit(main())
