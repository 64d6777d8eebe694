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


# The vertex layout `xi export` writes: three vertices per triangle, then faces (uchar 3, int i, i+1, i+2).
PLY_VERTEX = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]


def read_ply(path):
    """Triangles (k,3,3) and vertex normals (k,3,3), float32, of a PLY that `xi export` wrote."""
    import numpy as np
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    props = [line.split()[-1] for line in header if line.startswith("property float")]
    counts = {w[1]: int(w[2]) for w in (line.split() for line in header) if w[0] == "element"}
    if "format binary_little_endian 1.0" not in header or props != [p for p, _ in PLY_VERTEX] \
            or counts.get("vertex") != 3 * counts.get("face", -1):
        raise Unsupported(f"{path}: not a PLY file as `xi export` writes it")
    verts = np.frombuffer(data, np.dtype(PLY_VERTEX), counts["vertex"], end)
    faces = np.frombuffer(data, np.dtype([("n", "u1"), ("i", "<i4", (3,))]), counts["face"],
                          end + verts.nbytes)
    xyz = np.stack([verts[p] for p in "xyz"], axis=-1)
    nrm = np.stack([verts[p] for p in ("nx", "ny", "nz")], axis=-1)
    return xyz[faces["i"]], nrm[faces["i"]]


def write_ply(path, v, n):
    """A triangle soup (3 vertices per triangle, as xi stores them) as a binary PLY, normals optional."""
    import numpy as np
    k = len(v)
    cols = [v.reshape(-1, 3)] + ([n.reshape(-1, 3)] if n is not None else [])
    verts = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    faces = np.zeros(k, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"], faces["i"] = 3, np.arange(3 * k, dtype="<i4").reshape(k, 3)
    props = "xyz" if n is None else ["x", "y", "z", "nx", "ny", "nz"]
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {3 * k}\n"
              + "".join(f"property float {p}\n" for p in props)
              + f"element face {k}\nproperty list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(verts.tobytes())
        f.write(faces.tobytes())


def rgb(value):
    return {"type": "rgb", "value": [float(x) for x in value]}


def bsdf(m):
    """xi's material as a Mitsuba BSDF (and area emitter). xi scatters on both sides of every surface;
    Mitsuba's diffuse and conductor are one-sided, hence `twosided`."""
    kind = m["type"]
    emitter = None
    if kind in ("diffuse", "emitter"):
        if "radiance" in m:
            if m.get("two_sided", False):
                raise Unsupported("two-sided emitters (Mitsuba's area lights emit from the front face only)")
            emitter = {"type": "area", "radiance": rgb(m["radiance"])}
        b = {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": rgb(m.get("albedo", [0, 0, 0]))}}
    elif kind == "mirror":  # a perfect mirror: no Fresnel falloff (material 'none'), the albedo as tint
        b = {"type": "twosided", "bsdf": {"type": "conductor", "material": "none",
                                          "specular_reflectance": rgb(m.get("albedo", [1, 1, 1]))}}
    elif kind == "glass":
        tint = rgb(m.get("albedo", [1, 1, 1]))
        b = {"type": "dielectric", "int_ior": float(m.get("ior", 1.5)), "ext_ior": 1.0,
             "specular_reflectance": tint, "specular_transmittance": tint}
    else:
        raise Unsupported(f"material type '{kind}'")
    return b, emitter


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
         "sampler": {"type": sampler, "sample_count": 1}}  # (mi.render sets the spp)
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
    bg = s.get("background", [0, 0, 0])
    if max(bg) > 0:  # xi adds it to escaping rays; Mitsuba also samples it as a light: same expectation
        d["background"] = {"type": "constant", "radiance": rgb(bg)}

    export_dir = Path(export_dir)
    manifest = json.loads((export_dir / "manifest.json").read_text())
    for i, mesh in enumerate(manifest["meshes"]):
        if mesh["material"] not in s.get("materials", {}):  # an asset shape's own materials
            raise Unsupported(f"material '{mesh['material']}' (not one of the scene's own)")
        b, emitter = bsdf(s["materials"][mesh["material"]])
        v, n = read_ply(export_dir / mesh["file"])
        # The first flat_triangles have no vertex normals in xi (their face normal at each vertex): they go
        # to Mitsuba without normals too, so that each renderer interpolates normals on the same triangles.
        k = mesh["flat_triangles"]
        for part, (pv, pn) in (("flat", (v[:k], None)), ("smooth", (v[k:], n[k:]))):
            if not len(pv):
                continue
            path = export_dir / f"mitsuba-{i}-{part}.ply"
            write_ply(path, pv, pn)
            # face_normals: without it Mitsuba would smooth the normals of a mesh that has none
            shape = {"type": "ply", "filename": str(path), "face_normals": pn is None, "bsdf": b}
            if emitter:
                shape["emitter"] = emitter
            d[f"shape-{i}-{part}"] = shape
    return d, manifest["triangles"]
