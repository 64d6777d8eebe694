"""An xi JSON scene as a Blender scene for Cycles, and a worker that renders it (run by bench/.venv-bpy).

The geometry and materials of plain shapes come from xi itself, as for Mitsuba (bench/mitsuba_scene.py):
`xi export` writes the triangles xi renders, one PLY per material, and a manifest of the materials. An
`asset` shape (a glTF file) is instead read by Blender's own glTF importer (bpy.ops.import_scene.gltf), with
Blender's own mapping of glTF materials to its Principled BSDF, and moved by the shape's transform; the
export's triangles of that asset are left out. The camera comes from the JSON; the environment map and the
background from the export's manifest.

Frames: xi's world (+y up) maps to Blender's (+z up) as Blender's glTF importer maps glTF's: (x, y, z) ->
(x, -z, y), a rotation. xi's environment lookup (kernels/shared/environment.h: u = atan2(d.x, -d.z) / 2pi,
v = acos(d.y) / pi, row 0 at the zenith) is Cycles' equirectangular lookup of the direction turned by
90 - rotation degrees about Blender's +z (checked by probing single directions and by rendering the
background alone against xi's).

Render settings, the same for every mode: box pixel filter 1 px wide, no clamping, no glossy filter,
caustics on, view transform Standard (the EXR is linear float anyway), Cycles' max_bounces = xi's max depth
- 1 (Cycles counts bounces after the first hit, xi the path segments after the camera's: xi's depth 1 and
Cycles' 0 are both direct light only), all bounce kinds the same, persistent data on (the BVH and
the shaders are built once per scene, not in every timed render, as xi's renderSeconds leaves out its
BVH build and kernel compilation)."""
import json
import math
import os
import sys
import time
from pathlib import Path

sys.dont_write_bytecode = True
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import mitsuba_scene as ms  # noqa: E402  (read_ply and export only: numpy, no Mitsuba)

Unsupported = ms.Unsupported
export = ms.export


def to_blender(p):
    """A point or direction of xi's (and glTF's) +y-up world in Blender's +z-up one."""
    return (p[0], -p[2], p[1])


def xi_matrix(transform):
    """An xi shape `transform` as a 4x4 row-major matrix (list of rows) in xi's frame: scale, then rotate,
    then translate, or `matrix`."""
    import numpy as np
    if not transform:
        return np.eye(4)
    if "matrix" in transform:
        return np.array(transform["matrix"], float).reshape(4, 4)
    m = np.eye(4)
    s = transform.get("scale", 1)
    m[:3, :3] = np.diag([s] * 3 if isinstance(s, (int, float)) else s)
    if "rotate" in transform:
        axis = np.array(transform["rotate"]["axis"], float)
        axis /= np.linalg.norm(axis)
        a = math.radians(transform["rotate"]["degrees"])
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        r = np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k
        m[:3, :3] = r @ m[:3, :3]
    m[:3, 3] = transform.get("translate", [0, 0, 0])
    return m


def blender_matrix(m):
    """An xi-frame 4x4 as the same motion in Blender's frame: C m C^-1, C the frame change."""
    import numpy as np
    c = np.eye(4)
    c[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    return c @ m @ c.T


def settings(bpy, width, height, max_depth):
    s = bpy.context.scene
    s.render.engine = "CYCLES"
    cy = s.cycles
    cy.device = "CPU"
    cy.pixel_filter_type, cy.filter_width = "BOX", 1.0
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    cy.blur_glossy = 0.0
    cy.caustics_reflective = cy.caustics_refractive = True
    bounces = max(0, max_depth - 1)
    cy.max_bounces = cy.diffuse_bounces = cy.glossy_bounces = cy.transmission_bounces = bounces
    cy.volume_bounces = cy.transparent_max_bounces = bounces
    cy.use_animated_seed = False
    cy.use_auto_tile = False  # one tile: the frames here are small
    s.render.use_persistent_data = True
    s.render.threads_mode = "AUTO"
    s.render.film_transparent = False
    s.render.resolution_x, s.render.resolution_y, s.render.resolution_percentage = width, height, 100
    s.render.pixel_aspect_x = s.render.pixel_aspect_y = 1
    s.render.dither_intensity = 0
    s.view_settings.view_transform, s.view_settings.look = "Standard", "None"
    s.view_settings.exposure, s.view_settings.gamma = 0.0, 1.0
    img = s.render.image_settings
    img.media_type = "MULTI_LAYER_IMAGE"  # (Blender 5: the multilayer EXR is a media type, not a format)
    img.file_format, img.color_depth, img.exr_codec = "OPEN_EXR_MULTILAYER", "32", "ZIP"
    s.view_layers[0].cycles.pass_debug_sample_count = True  # per-pixel samples, as xi's spp layer
    return s


def camera(bpy, scene, cam, dist_hint):
    """xi's pinhole camera: position, look_at, up and vertical fov (or focal length and film height)."""
    import numpy as np
    from mathutils import Matrix
    if cam.get("aperture_radius", 0) > 0:
        raise Unsupported("a thin-lens camera")
    pos, look, up = (np.array(to_blender(cam[k]), float) for k in ("position", "look_at", "up"))
    forward = look - pos
    dist = float(np.linalg.norm(forward))
    forward /= dist
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    fov = cam.get("fov") or math.degrees(2 * math.atan(cam["film_height_mm"] / 2 / cam["focal_length_mm"]))
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "VERTICAL"
    data.angle_y = math.radians(fov)
    data.clip_start, data.clip_end = 1e-3 * dist, 1e4 * max(dist, dist_hint)
    obj = bpy.data.objects.new("camera", data)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, true_up, -forward, pos  # Blender cameras look along -z
    obj.matrix_world = Matrix(m.tolist())
    scene.collection.objects.link(obj)
    scene.camera = obj


def world(bpy, scene, manifest):
    """The environment map (strength, rotation) or the constant background."""
    w = bpy.data.worlds.new("world")
    scene.world = w
    nodes, links = w.node_tree.nodes, w.node_tree.links
    background = nodes["Background"]
    env = manifest.get("environment")
    if env:
        tex = nodes.new("ShaderNodeTexEnvironment")
        tex.image = bpy.data.images.load(env["file"])
        tex.image.colorspace_settings.name = "Linear Rec.709"
        tex.interpolation, tex.projection = "Linear", "EQUIRECTANGULAR"
        coords, mapping = nodes.new("ShaderNodeTexCoord"), nodes.new("ShaderNodeMapping")
        mapping.vector_type = "VECTOR"
        mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(90.0 - env["rotation"]))
        links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
        links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
        links.new(tex.outputs["Color"], background.inputs["Color"])
        background.inputs["Strength"].default_value = float(env["strength"])
    else:
        background.inputs["Color"].default_value = (*manifest.get("background", [0, 0, 0]), 1.0)
        background.inputs["Strength"].default_value = 1.0


def image_node(bpy, nodes, links, slot, export_dir, colour, uv_node):
    """A texture slot of the manifest (xi's decoded texels, sRGB for colour) as an Image Texture node."""
    if slot["texcoord"] != 0:
        raise Unsupported(f"texture coordinate set {slot['texcoord']}")
    if slot["wrap_s"] != slot["wrap_t"]:
        raise Unsupported("different wrap modes in u and v")
    identity = [1, 0, 0, 0, 1, 0, 0, 0, 1]
    if any(abs(a - b) > 1e-6 for a, b in zip(slot["transform"], identity)):
        raise Unsupported("a texture transform")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = bpy.data.images.load(str(Path(export_dir) / slot["file"]))
    tex.image.colorspace_settings.name = "sRGB" if colour else "Non-Color"
    tex.interpolation = "Linear"
    tex.extension = {"repeat": "REPEAT", "clamp": "EXTEND", "mirror": "MIRROR"}[slot["wrap_s"]]
    links.new(uv_node.outputs["UV"], tex.inputs["Vector"])
    return tex


def material(bpy, m, export_dir):
    """xi's material (a manifest entry of `xi export`) as a Cycles node material. xi's emitters emit from
    the front face only unless two-sided: the emission is mixed out on back faces."""
    if m["alpha_mode"] != "opaque":
        raise Unsupported(f"material '{m['name']}': alpha mode {m['alpha_mode']}")
    for slot in ("normal_texture", "emissive_texture", "metallic_roughness_texture"):
        if slot in m["textures"]:
            raise Unsupported(f"material '{m['name']}': {slot}")
    mat = bpy.data.materials.new(m["name"])
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    uv = nodes.new("ShaderNodeUVMap")
    base_slot = m["textures"].get("base_color_texture")
    kind = m["type"]
    if kind in ("diffuse", "emitter"):
        surface = nodes.new("ShaderNodeBsdfDiffuse")
        surface.inputs["Roughness"].default_value = 0.0  # Lambert
        colour_input = surface.inputs["Color"]
    elif kind == "mirror":
        surface = nodes.new("ShaderNodeBsdfGlossy")  # no Fresnel: the albedo as tint at every angle
        surface.distribution = "SHARP"
        colour_input = surface.inputs["Color"]
    elif kind == "glass":
        surface = nodes.new("ShaderNodeBsdfGlass")
        surface.distribution = "SHARP"
        surface.inputs["IOR"].default_value = m["ior"]
        colour_input = surface.inputs["Color"]
    elif kind == "pbr":
        surface = nodes.new("ShaderNodeBsdfPrincipled")
        surface.inputs["Metallic"].default_value = m["metallic"]
        surface.inputs["Roughness"].default_value = m["roughness"]
        surface.inputs["IOR"].default_value = m["ior"]
        surface.inputs["Transmission Weight"].default_value = m["transmission"]
        colour_input = surface.inputs["Base Color"]
    else:
        raise Unsupported(f"material type '{kind}'")
    colour_input.default_value = (*m["albedo"], 1.0)
    if base_slot is not None:
        if any(abs(f - 1) > 1e-6 for f in m["albedo"]):
            raise Unsupported(f"material '{m['name']}': a texture times a factor other than 1")
        links.new(image_node(bpy, nodes, links, base_slot, export_dir, True, uv).outputs["Color"], colour_input)
    shader = surface.outputs[0]
    if max(m["emission"]) > 0:
        emission = nodes.new("ShaderNodeEmission")
        emission.inputs["Color"].default_value = (*m["emission"], 1.0)
        emission.inputs["Strength"].default_value = 1.0  # Cycles' emission strength 1 is radiance 1
        add = nodes.new("ShaderNodeAddShader")
        links.new(shader, add.inputs[0])
        links.new(emission.outputs[0], add.inputs[1])
        if m["two_sided"]:
            shader = add.outputs[0]
            mat.cycles.emission_sampling = "FRONT_BACK"
        else:
            geometry, mix = nodes.new("ShaderNodeNewGeometry"), nodes.new("ShaderNodeMixShader")
            links.new(geometry.outputs["Backfacing"], mix.inputs["Fac"])
            links.new(add.outputs[0], mix.inputs[1])
            links.new(surface.outputs[0], mix.inputs[2])
            shader = mix.outputs[0]
            mat.cycles.emission_sampling = "FRONT"
    links.new(shader, out.inputs["Surface"])
    return mat


def mesh_object(bpy, scene, name, v, n, uv, mat):
    """A triangle soup (k, 3, 3) as a mesh object: with N, shaded smooth with those normals per corner;
    without, flat. UV (k, 3, 2), glTF's v-down coordinates, goes in as Blender's v-up."""
    import numpy as np
    k = len(v)
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(3 * k)
    mesh.vertices.foreach_set("co", np.ascontiguousarray(v.reshape(-1, 3)[:, [0, 2, 1]] * [1, -1, 1],
                                                         np.float32).ravel())
    mesh.loops.add(3 * k)
    mesh.loops.foreach_set("vertex_index", np.arange(3 * k, dtype=np.int32))
    mesh.polygons.add(k)
    mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * k, 3, dtype=np.int32))
    mesh.update()
    if uv is not None:
        layer = mesh.uv_layers.new(name="UVMap")
        flipped = uv.reshape(-1, 2).astype(np.float64) * [1, -1] + [0, 1]
        layer.data.foreach_set("uv", np.ascontiguousarray(flipped, np.float32).ravel())
    if n is not None:
        mesh.polygons.foreach_set("use_smooth", np.ones(k, dtype=bool))
        normals = n.reshape(-1, 3)[:, [0, 2, 1]] * [1, -1, 1]
        mesh.normals_split_custom_set(normals.tolist())
    mesh.materials.append(mat)
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    return obj


def light(bpy, scene, i, l):
    """A punctual light of the manifest in Blender's units: a point light of power P W has radiant
    intensity P / 4pi W/sr; a sun's strength is its irradiance, W/m^2, as xi's."""
    from mathutils import Vector
    kind, peak = l["type"], max(max(l["intensity"]), 1e-30)
    colour = [c / peak for c in l["intensity"]]
    if kind == "point":
        data = bpy.data.lights.new(f"light-{i}", "POINT")
        data.energy, data.shadow_soft_size, data.color = 4 * math.pi * peak, 0.0, colour
        obj = bpy.data.objects.new(f"light-{i}", data)
        obj.location = to_blender(l["position"])
    elif kind == "directional":
        data = bpy.data.lights.new(f"light-{i}", "SUN")
        data.energy, data.angle, data.color = peak, 2 * math.radians(l["angular_radius_degrees"]), colour
        obj = bpy.data.objects.new(f"light-{i}", data)
        obj.rotation_euler = Vector(to_blender(l["direction"])).to_track_quat("-Z", "Y").to_euler()
    else:
        raise Unsupported(f"light type '{kind}'")
    scene.collection.objects.link(obj)


def import_assets(bpy, scene_json, scene_dir):
    """Each `asset` shape through Blender's glTF importer, moved by its transform. Returns the asset files
    (their materials, named '<file>:<material>' by xi, are left out of the export's meshes)."""
    from mathutils import Matrix
    files = []
    for shape in scene_json.get("shapes", []):
        if shape.get("type") != "asset":
            continue
        path = (scene_dir / shape["file"]).resolve()
        if path.suffix.lower() not in (".gltf", ".glb"):
            raise Unsupported(f"an asset that is not glTF: {path.name}")
        before = set(bpy.data.objects)
        bpy.ops.import_scene.gltf(filepath=str(path))
        for obj in [o for o in bpy.data.objects if o not in before and o.type == "CAMERA"]:
            bpy.data.objects.remove(obj)  # xi ignores an asset shape's cameras (its lights move with it)
        added = [o for o in bpy.data.objects if o not in before]
        move = Matrix(blender_matrix(xi_matrix(shape.get("transform"))).tolist())
        for obj in added:
            if obj.name in bpy.data.objects and obj.parent is None:
                obj.matrix_world = move @ obj.matrix_world
        files.append(shape["file"])
    return files


def convert(bpy, scene_file, export_dir, width, height, max_depth):
    """Builds the Blender scene of SCENE_FILE (with `xi export`'s output in EXPORT_DIR) in a fresh factory
    scene. Returns the triangle count of the export (the assets' included)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    s = json.loads(Path(scene_file).read_text())
    export_dir = Path(export_dir)
    manifest = json.loads((export_dir / "manifest.json").read_text())
    scene = settings(bpy, width, height, max_depth)
    asset_files = import_assets(bpy, s, Path(scene_file).resolve().parent)
    extent = 1.0
    for i, mesh in enumerate(manifest["meshes"]):
        m = manifest["materials"][mesh["material_index"]]
        if any(m["name"].startswith((f"{f}:", f"{Path(f).name}:")) for f in asset_files):
            continue  # the glTF importer made these
        mat = material(bpy, m, export_dir)
        v, n, uv = ms.read_ply(export_dir / mesh["file"])
        extent = max(extent, float(abs(v).max()))
        k = mesh["flat_triangles"]
        for part, (pv, pn, puv) in (("flat", (v[:k], None, None if uv is None else uv[:k])),
                                    ("smooth", (v[k:], n[k:], None if uv is None else uv[k:]))):
            if len(pv):
                mesh_object(bpy, scene, f"mesh-{i}-{part}", pv, pn, puv, mat)
    if manifest.get("lights") and asset_files:
        raise Unsupported("punctual lights beside an asset (the importer brings the asset's own)")
    for i, l in enumerate(manifest.get("lights", [])):
        light(bpy, scene, i, l)
    camera(bpy, scene, s["camera"], extent)
    world(bpy, scene, manifest)
    return manifest["triangles"]


def render(bpy, spp, seed, out, adaptive_threshold=None, min_spp=0, denoise=False):
    """One render; returns the seconds of bpy.ops.render.render (scene sync, the samples, any denoising)
    and writes OUT, a multilayer EXR (ZIP): the combined pass and the debug sample count."""
    scene = bpy.context.scene
    cy = scene.cycles
    cy.samples, cy.seed = spp, seed
    cy.use_adaptive_sampling = adaptive_threshold is not None
    if adaptive_threshold is not None:
        cy.adaptive_threshold, cy.adaptive_min_samples = adaptive_threshold, min_spp
    cy.use_denoising = denoise
    if denoise:
        cy.denoiser, cy.denoising_input_passes = "OPENIMAGEDENOISE", "RGB_ALBEDO_NORMAL"
        cy.denoising_prefilter, cy.denoising_quality = "ACCURATE", "HIGH"
    t0 = time.perf_counter()
    bpy.ops.render.render()
    seconds = time.perf_counter() - t0
    bpy.data.images["Render Result"].save_render(str(out))
    return seconds


def worker():
    """Answers one JSON line per request on stdin: hello, load, render."""
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # Blender's messages go to stderr, not into the replies
    import bpy
    for line in sys.stdin:
        req = json.loads(line)
        cmd = req["cmd"]
        try:
            if cmd == "hello":
                bpy.context.scene.render.engine = "CYCLES"
                prefs = bpy.context.preferences.addons["cycles"].preferences
                cpus = [d.name for d in prefs.get_devices_for_type("CPU")]
                res = dict(version=bpy.app.version_string, device=cpus[0] if cpus else "CPU",
                           threads=os.cpu_count())
            elif cmd == "load":
                res = dict(triangles=convert(bpy, req["scene"], req["export"], req["width"], req["height"],
                                             req["max_depth"]),
                           pattern=bpy.context.scene.cycles.sampling_pattern)
            elif cmd == "render":
                res = dict(seconds=render(bpy, req["spp"], req["seed"], req["out"], req.get("adaptive_threshold"),
                                          req.get("min_spp", 0), req.get("denoise", False)))
            else:
                raise ValueError(f"unknown request {cmd}")
        except Unsupported as e:
            res = dict(unsupported=str(e))
        reply.write(json.dumps(res) + "\n")


if __name__ == "__main__":
    worker()
