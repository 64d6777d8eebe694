"""An xi JSON scene as a Mitsuba 3 scene: camera, materials, emitters and xi's own triangles.

The geometry comes from xi itself: `xi export SCENE DIR` writes the triangles xi renders (quads split,
spheres as icospheres, meshes loaded and cleaned, transforms applied), in world space, one binary PLY per
material with a manifest.json naming each file's material. export() runs it (standard library only);
convert() reads that folder and the scene's JSON into a dict for mitsuba.load_dict (needs numpy and
mitsuba, so it runs in bench/.venv)."""
import json
import math
import subprocess
from pathlib import Path


class Unsupported(Exception):
    """A scene feature the conversion cannot express in Mitsuba: the scene is skipped for Mitsuba."""


def export(xi, scene, out_dir):
    """`xi export SCENE OUT_DIR`: xi's triangles as PLY files and their manifest in OUT_DIR."""
    r = subprocess.run([str(xi), "export", str(scene), str(out_dir)], capture_output=True, text=True)
    if r.returncode != 0:
        raise Unsupported(f"xi export {scene} failed: {r.stderr.strip()}")
    return out_dir


# The vertex layout `xi export` writes: three vertices per triangle, then faces (uchar 3, int i, i+1, i+2);
# a material with textures adds u, v (set 0, v down the image as glTF).
PLY_VERTEX = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
PLY_UV = [("u", "<f4"), ("v", "<f4")]


def read_ply(path):
    """Triangles (k,3,3), vertex normals (k,3,3) and texture coordinates (k,3,2, or None), float32, of a
    PLY that `xi export` wrote."""
    import numpy as np
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    props = [line.split()[-1] for line in header if line.startswith("property float")]
    counts = {w[1]: int(w[2]) for w in (line.split() for line in header) if w[0] == "element"}
    layout = PLY_VERTEX + PLY_UV if props == [p for p, _ in PLY_VERTEX + PLY_UV] else PLY_VERTEX
    if "format binary_little_endian 1.0" not in header or props != [p for p, _ in layout] \
            or counts.get("vertex") != 3 * counts.get("face", -1):
        raise Unsupported(f"{path}: not a PLY file as `xi export` writes it")
    verts = np.frombuffer(data, np.dtype(layout), counts["vertex"], end)
    faces = np.frombuffer(data, np.dtype([("n", "u1"), ("i", "<i4", (3,))]), counts["face"],
                          end + verts.nbytes)
    xyz = np.stack([verts[p] for p in "xyz"], axis=-1)
    nrm = np.stack([verts[p] for p in ("nx", "ny", "nz")], axis=-1)
    uv = np.stack([verts["u"], verts["v"]], axis=-1)[faces["i"]] if layout != PLY_VERTEX else None
    return xyz[faces["i"]], nrm[faces["i"]], uv


def write_ply(path, v, n, uv=None):
    """A triangle soup (3 vertices per triangle, as xi stores them) as a binary PLY, normals and texture
    coordinates optional (Mitsuba's PLY loader reads u, v as they are: no flip)."""
    import numpy as np
    k = len(v)
    cols = [v.reshape(-1, 3)] + ([n.reshape(-1, 3)] if n is not None else []) \
        + ([uv.reshape(-1, 2)] if uv is not None else [])
    verts = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    faces = np.zeros(k, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"], faces["i"] = 3, np.arange(3 * k, dtype="<i4").reshape(k, 3)
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if n is not None else []) + (["u", "v"] if uv is not None else [])
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {3 * k}\n"
              + "".join(f"property float {p}\n" for p in props)
              + f"element face {k}\nproperty list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(verts.tobytes())
        f.write(faces.tobytes())


def rgb(value):
    return {"type": "rgb", "value": [float(x) for x in value]}


def bitmap(slot, filename, raw, what):
    """Mitsuba's `bitmap` of FILENAME read through a texture slot of the manifest: bilinear, the slot's wrap
    mode and KHR_texture_transform. Mitsuba reads the PLY's u, v and the image as glTF does ((0, 0) the
    top-left corner, v down), so the transform goes unchanged. RAW: data, not sRGB-decoded."""
    import mitsuba as mi
    if slot["texcoord"] != 0:
        raise Unsupported(f"{what}: texture coordinate set {slot['texcoord']} (the export has set 0)")
    if slot["wrap_s"] != slot["wrap_t"]:
        raise Unsupported(f"{what}: different wrap modes in u and v")
    return {"type": "bitmap", "filename": str(filename), "filter_type": "bilinear", "wrap_mode": slot["wrap_s"],
            "raw": raw,
            "to_uv": mi.ScalarTransform3f(mi.ScalarMatrix3f([slot["transform"][3 * r:3 * r + 3] for r in range(3)]))}


def texture(slot, export_dir, factor, what):
    """A colour texture slot as Mitsuba's sRGB-decoded `bitmap` times FACTOR, or FACTOR as an RGB where there
    is no texture."""
    if slot is None:
        return rgb(factor)
    if any(abs(f - 1) > 1e-6 for f in factor):
        raise Unsupported(f"{what}: a texture times a factor other than 1")
    return bitmap(slot, Path(export_dir) / slot["file"], False, what)


def data_channel(slot, export_dir, channel, factor, out_name):
    """Channel CHANNEL (1: G, 2: B) of a data texture times FACTOR, written as a one-channel linear EXR and
    read back as Mitsuba's raw `bitmap`: glTF packs roughness (G) and metallic (B) in one image, a Mitsuba
    parameter reads one value."""
    import mitsuba as mi
    import numpy as np
    pixels = np.array(mi.Bitmap(str(Path(export_dir) / slot["file"])), dtype=np.float32) / 255.0
    path = Path(export_dir) / f"mitsuba-{out_name}.exr"
    mi.Bitmap(np.ascontiguousarray(pixels[..., channel:channel + 1] * factor)).write(str(path))
    return bitmap(slot, path, True, out_name)


def normal_mapped(b, m, export_dir, name):
    """B under Mitsuba's `normalmap` of the material's tangent-space normal texture, its xy scaled by
    normal_scale as glTF's (Mitsuba's tangent frame is dp/du of the texture coordinates: xi's where the file
    has no tangents)."""
    import mitsuba as mi
    import numpy as np
    slot = m["textures"]["normal_texture"]
    t = np.array(mi.Bitmap(str(Path(export_dir) / slot["file"])), dtype=np.float32)[..., :3] / 255.0
    n = (2.0 * t - 1.0) * np.array([m["normal_scale"], m["normal_scale"], 1.0], dtype=np.float32)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
    path = Path(export_dir) / f"mitsuba-{name}-normal.exr"
    mi.Bitmap(np.ascontiguousarray(0.5 * n + 0.5)).write(str(path))
    return {"type": "normalmap", "bsdf": b, "normalmap": bitmap(slot, path, True, f"material '{m['name']}'")}


def conductor_eta_k(f0):
    """Real eta, k = 0 per channel whose normal-incidence Fresnel reflectance is F0 (Gulbrandsen 2014 with
    edge tint 0: n = (1 + sqrt r) / (1 - sqrt r)): exact Fresnel rising to 1 at grazing as Schlick's does."""
    eta = [(1 + math.sqrt(r)) / (1 - math.sqrt(r)) for r in f0]
    return rgb(eta), rgb([0.0, 0.0, 0.0])


# Mitsuba's roughplastic loses much of its base's light at high roughness (a base of albedo 0.19 under a
# white sky reflects 0.207 at alpha 0.09, 0.149 at 0.36, 0.107 at 0.64), which xi's layer and principled keep.
ROUGHPLASTIC_LIMIT = 0.3


def pbr_bsdf(m, export_dir):
    """xi's glTF metallic-roughness material as the closest Mitsuba BSDF (bench/README.md says how each
    differs): metallic 1 -> roughconductor, metallic 0 -> roughplastic up to roughness ROUGHPLASTIC_LIMIT,
    principled above it, between or with a metallic-roughness texture; a normal texture -> Mitsuba's normalmap
    over it."""
    tex = m["textures"]
    if m["transmission"] > 0:
        raise Unsupported(f"material '{m['name']}': transmission")
    base = texture(tex.get("base_color_texture"), export_dir, m["albedo"], m["name"])
    r, metallic = m["roughness"], m["metallic"]
    name = f"material-{m['index']}"
    if "metallic_roughness_texture" in tex:
        slot = tex["metallic_roughness_texture"]
        b = {"type": "principled", "base_color": base, "eta": m["ior"], "spec_tint": 0.0, "spec_trans": 0.0,
             "sheen": 0.0, "clearcoat": 0.0,
             "roughness": data_channel(slot, export_dir, 1, r, f"{name}-roughness"),
             "metallic": data_channel(slot, export_dir, 2, metallic, f"{name}-metallic")}
        b = normal_mapped(b, m, export_dir, name) if "normal_texture" in tex else b
        return {"type": "twosided", "bsdf": b}
    delta = r < 0.01  # xi's delta lobes
    alpha = r * r
    rough = {"distribution": "ggx", "alpha": alpha, "sample_visible": True}
    if metallic >= 1:
        if "base_color_texture" in tex or all(c >= 1 for c in m["albedo"]):
            # Fresnel 1 (base colour 1: Schlick's is 1 too) or the texture as a constant reflectance
            b = {"material": "none", "specular_reflectance": base}
        else:
            f0 = [min(c, 0.999999) for c in m["albedo"]]
            eta, k = conductor_eta_k(f0)
            b = {"eta": eta, "k": k}
        b.update({"type": "conductor"} if delta else dict(type="roughconductor", **rough))
    elif metallic <= 0 and r <= ROUGHPLASTIC_LIMIT:
        b = {"int_ior": m["ior"], "ext_ior": 1.0, "diffuse_reflectance": base, "nonlinear": False}
        b.update({"type": "plastic"} if delta else dict(type="roughplastic", **rough))
    else:
        if "base_color_texture" in tex and metallic > 0:
            raise Unsupported(f"material '{m['name']}': a textured partly metallic material")
        b = {"type": "principled", "base_color": base, "metallic": metallic, "roughness": max(r, 0.01),
             "eta": m["ior"], "spec_tint": 0.0, "spec_trans": 0.0, "sheen": 0.0, "clearcoat": 0.0}
    b = normal_mapped(b, m, export_dir, name) if "normal_texture" in tex else b
    return {"type": "twosided", "bsdf": b}


def bsdf(m, export_dir):
    """xi's material (a manifest entry of `xi export`) as a Mitsuba BSDF and area emitter, or None.
    xi scatters on both sides of every surface; Mitsuba's diffuse and conductor are one-sided, hence
    `twosided`."""
    kind, emitter = m["type"], None
    if m["alpha_mode"] != "opaque":
        raise Unsupported(f"material '{m['name']}': alpha mode {m['alpha_mode']}")
    if "emissive_texture" in m["textures"] or ("normal_texture" in m["textures"] and kind != "pbr"):
        raise Unsupported(f"material '{m['name']}': an emissive texture, or a normal texture on a {kind} material")
    if max(m["emission"]) > 0:
        if m["two_sided"]:
            raise Unsupported("two-sided emitters (Mitsuba's area lights emit from the front face only)")
        emitter = {"type": "area", "radiance": rgb(m["emission"])}
    if kind == "diffuse":
        refl = texture(m["textures"].get("base_color_texture"), export_dir, m["albedo"], m["name"])
        b = {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": refl}}
    elif kind == "mirror":  # a perfect mirror: no Fresnel falloff (material 'none'), the albedo as tint
        b = {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                          "specular_reflectance": rgb(m["albedo"])}}
    elif kind == "glass":
        tint = rgb(m["albedo"])
        b = {"type": "dielectric", "int_ior": float(m["ior"]), "ext_ior": 1.0,
             "specular_reflectance": tint, "specular_transmittance": tint}
    elif kind == "pbr":
        b = pbr_bsdf(m, export_dir)
    else:
        raise Unsupported(f"material type '{kind}'")
    return b, emitter


def mitsuba_envmap(file, path):
    """xi's environment map resampled so that Mitsuba's `envmap` looks up the same radiance everywhere.
    Both put texel column x at u = (x + 1/2) / W and wrap in u; in v xi puts row y at the centre of its
    cell, v = (y + 1/2) / H, clamping beyond the first and last centres, while Mitsuba 3.9 puts rows 0 and
    H - 1 on the poles, v = y / (H - 1). A W x (2H + 1) map whose rows sit at v = y / 2H (the poles, each
    of xi's row centres and the midpoints between them) holds xi's bilinear function on Mitsuba's grid,
    so Mitsuba's bilinear interpolation of it is xi's function exactly. Written to PATH (an EXR)."""
    import mitsuba as mi
    import numpy as np
    img = np.array(mi.Bitmap(str(file)).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False),
                   np.float64)
    out = np.empty((2 * img.shape[0] + 1,) + img.shape[1:])
    out[1::2] = img                              # xi's row centres
    out[2:-1:2] = 0.5 * (img[:-1] + img[1:])     # halfway between them
    out[0], out[-1] = img[0], img[-1]            # the poles: xi clamps to its first and last rows
    mi.Bitmap(out.astype(np.float32), mi.Bitmap.PixelFormat.RGB).write(str(path))
    return path


def light(l):
    """A punctual light of the manifest as a Mitsuba emitter (same units: W/sr, W/m^2)."""
    import mitsuba as mi
    kind = l["type"]
    if kind == "point":
        return {"type": "point", "position": l["position"], "intensity": rgb(l["intensity"])}
    if kind == "spot":  # Mitsuba's falloff is linear in the angle from beam_width to cutoff; glTF's differs
        pos, d = l["position"], l["direction"]
        up = [0, 1, 0] if abs(d[1]) < 0.9 else [1, 0, 0]
        return {"type": "spot", "intensity": rgb(l["intensity"]), "cutoff_angle": l["outer_cone_degrees"],
                "beam_width": l["inner_cone_degrees"],
                "to_world": mi.ScalarTransform4f().look_at(origin=pos, target=[p + q for p, q in zip(pos, d)], up=up)}
    if kind == "directional":
        if l["angular_radius_degrees"] > 0:
            raise Unsupported(f"light '{l['name']}': a sun of angular radius > 0 (Mitsuba has no cone light)")
        return {"type": "directional", "direction": l["direction"], "irradiance": rgb(l["intensity"])}
    raise Unsupported(f"light type '{kind}'")


def sensor(cam, width, height, sampler):
    """xi's camera as a perspective (or thin-lens) sensor with the same vertical fov."""
    import mitsuba as mi
    import numpy as np
    pos, look = np.array(cam["position"], float), np.array(cam["look_at"], float)
    dist = float(np.linalg.norm(look - pos))
    fov = cam.get("fov") or math.degrees(2 * math.atan(cam["film_height_mm"] / 2 / cam["focal_length_mm"]))
    # Mitsuba's look_at puts camera +x at cross(up, forward), so the image's x axis is cross(forward, up),
    # as in xi. Clip planes: xi has none; these keep Mitsuba's default near/far ratio (1e6) at the scene's scale.
    s = {"type": "perspective", "fov": fov, "fov_axis": "y",
         "to_world": mi.ScalarTransform4f().look_at(origin=cam["position"], target=cam["look_at"], up=cam["up"]),
         "near_clip": 1e-3 * dist, "far_clip": 1e3 * dist,
         "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                  "pixel_format": "rgb", "component_format": "float32"},
         # mi.render sets the spp; ldsampler rounds any count below 4 up to 4 (with a warning)
         "sampler": {"type": sampler, "sample_count": 4 if sampler == "ldsampler" else 1}}
    if cam.get("aperture_radius", 0) > 0:
        s.update(type="thinlens", aperture_radius=cam["aperture_radius"], focus_distance=cam.get("focus_distance", dist))
    return s


def convert(scene_file, export_dir, width, height, max_depth, sampler):
    """xi's JSON scene as a Mitsuba scene dict and its triangle count. EXPORT_DIR holds what `xi export`
    wrote for it (export()); each material's triangles become one or two PLY shapes there: those without
    vertex normals with face normals, the others with xi's vertex normals."""
    s = json.loads(Path(scene_file).read_text())
    d = {"type": "scene", "sensor": sensor(s["camera"], width, height, sampler),
         # xi counts bounces (1 = direct light), Mitsuba path vertices (2 = direct light)
         "integrator": {"type": "path", "max_depth": max_depth + 1}}
    export_dir = Path(export_dir)
    manifest = json.loads((export_dir / "manifest.json").read_text())
    env = manifest.get("environment")
    bg = s.get("background", [0, 0, 0])
    if env:  # xi's orientation is Mitsuba's by design, its rows' placement not: resampled
        import mitsuba as mi
        resampled = mitsuba_envmap(env["file"], export_dir / "mitsuba-environment.exr")
        d["environment"] = {"type": "envmap", "filename": str(resampled), "scale": float(env["strength"]),
                            "to_world": mi.ScalarTransform4f().rotate(axis=[0, 1, 0], angle=env["rotation"])}
    elif max(bg) > 0:  # xi adds it to escaping rays; Mitsuba also samples it as a light: same expectation
        d["background"] = {"type": "constant", "radiance": rgb(bg)}
    for i, l in enumerate(manifest.get("lights", [])):
        d[f"light-{i}"] = light(l)

    for i, mesh in enumerate(manifest["meshes"]):
        b, emitter = bsdf(dict(manifest["materials"][mesh["material_index"]], index=mesh["material_index"]),
                          export_dir)
        v, n, uv = read_ply(export_dir / mesh["file"])
        # The first flat_triangles have no vertex normals in xi (their face normal at each vertex): they go
        # to Mitsuba without normals too, so that each renderer interpolates normals on the same triangles.
        k = mesh["flat_triangles"]
        for part, (pv, pn, puv) in (("flat", (v[:k], None, None if uv is None else uv[:k])),
                                    ("smooth", (v[k:], n[k:], None if uv is None else uv[k:]))):
            if not len(pv):
                continue
            path = export_dir / f"mitsuba-{i}-{part}.ply"
            write_ply(path, pv, pn, puv)
            # face_normals: without it Mitsuba would smooth the normals of a mesh that has none
            shape = {"type": "ply", "filename": str(path), "face_normals": pn is None, "bsdf": b}
            if emitter:
                shape["emitter"] = emitter
            d[f"shape-{i}-{part}"] = shape
    return d, manifest["triangles"]
