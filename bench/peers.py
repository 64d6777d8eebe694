#!/usr/bin/python3
"""xi against Mitsuba 3 on the same scenes, and optionally against Embree's ray-tracing ceiling.

Speed: `xi render` and Mitsuba 3's `path` integrator render each scene at the same resolution, spp and path
length, alternately, after one untimed warm-up each (kernel compilation excluded on both sides); medians of
--runs. The ratio is xi's time per sample over Mitsuba's (<= 1: xi is faster). --error adds each one's
relMSE against a high-spp xi reference and the efficiency 1/(relMSE x seconds). --check renders both at
64x64 with many spp and compares their mean radiance, to show that the scene conversion is right.

Mitsuba runs in bench/.venv (made by bench/setup-mitsuba.sh) in a worker process: this file, run by the
venv's python with --worker, converting xi's JSON scene itself (see convert())."""
import argparse
import json
import math
import os
import re
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

DEFAULT_SCENES = ["cornell-box", "bench/scenes/engine.json"]
VENV = c.ROOT / "bench" / ".venv"
MESH_CACHE = c.ROOT / "bench" / ".cache" / "meshes"  # Assimp exports of mesh files (ignored by git)
# Mitsuba 3.9.1's samplers and the spp each takes without rounding it (to a square, a power of two).
MITSUBA_SAMPLERS = {"independent": lambda n: n > 0,
                    "stratified": lambda n: n > 0 and math.isqrt(n) ** 2 == n,
                    "multijitter": lambda n: n > 0 and math.isqrt(n) ** 2 == n,
                    "ldsampler": lambda n: n > 0 and n & (n - 1) == 0}
MITSUBA_SAMPLER_SPP = {"independent": "any spp", "stratified": "a square spp", "multijitter": "a square spp",
                       "ldsampler": "a power-of-two spp"}


# ---------------------------------------------------------------------------------------------------------
# Worker side: runs under bench/.venv/bin/python with numpy and mitsuba.

class Unsupported(Exception):
    """A scene feature the conversion cannot express in Mitsuba: the scene is skipped for Mitsuba."""


def rotation(axis, degrees):
    """glm::rotate's matrix: right-handed rotation by DEGREES about AXIS (Rodrigues)."""
    import numpy as np
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(degrees)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return math.cos(t) * np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * np.outer(a, a)


def xi_matrix(t):
    """A shape's `transform` as a 4x4 matrix, as xi builds it: scale, then rotate, then translate."""
    import numpy as np
    m = np.eye(4)
    if not t:
        return m
    if "matrix" in t:
        return np.array(t["matrix"], float).reshape(4, 4)  # row-major in the file
    s = t.get("scale", 1.0)
    m[:3, :3] = np.diag(s if isinstance(s, list) else [s] * 3)
    if "rotate" in t:
        m[:3, :3] = rotation(t["rotate"]["axis"], t["rotate"]["degrees"]) @ m[:3, :3]
    m[:3, 3] = t.get("translate", [0, 0, 0])
    return m


def transform(m, v, n):
    """Applies M to triangles V (k,3,3) and their normals N (or None) as xi's apply() does: double math,
    normals by the inverse transpose, winding swapped by a mirroring transform to keep the front face."""
    import numpy as np
    lin = m[:3, :3]
    v = (v.astype(np.float64) @ lin.T + m[:3, 3]).astype(np.float32)
    if n is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            n = n.astype(np.float64) @ np.linalg.inv(lin)
            n = (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)
    if np.linalg.det(lin) < 0:
        v = v[:, [0, 2, 1]]
        n = None if n is None else n[:, [0, 2, 1]]
    return v, n


def icosphere(levels):
    """xi's icosphere (host/src/scene/scene.cpp), vertex for vertex: (unit positions = normals (k,3,3) float32)."""
    import numpy as np
    g = (1 + math.sqrt(5)) / 2
    p = [np.array(v, float) / np.linalg.norm(v) for v in (
        (-1, g, 0), (1, g, 0), (-1, -g, 0), (1, -g, 0), (0, -1, g), (0, 1, g),
        (0, -1, -g), (0, 1, -g), (g, 0, -1), (g, 0, 1), (-g, 0, -1), (-g, 0, 1))]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5),
             (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(levels):
        mids = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in mids:
                mids[key] = len(p)
                q = p[a] + p[b]
                p.append(q / np.linalg.norm(q))
            return mids[key]
        nxt = []
        for a, b, cc in faces:
            ab, bc, ca = mid(a, b), mid(b, cc), mid(cc, a)
            nxt += [(a, ab, ca), (b, bc, ab), (cc, ca, bc), (ab, bc, ca)]
        faces = nxt
    pts, f = np.array(p), np.array(faces)
    tri = pts[f]  # (k,3,3) double
    outward = np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri.sum(axis=1)) >= 0
    f[~outward] = f[~outward][:, [0, 2, 1]]
    return pts[f].astype(np.float32)


PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "<i2", "int16": "<i2",
             "ushort": "<u2", "uint16": "<u2", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
             "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8"}


def read_ply(path):
    """Triangles (k,3,3) and normals (or None) of a binary little-endian PLY, as `assimp export` writes it."""
    import numpy as np
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    elements = []  # (name, count, [(prop, type)] or list types)
    for line in data[:end].decode("ascii").splitlines():
        w = line.split()
        if w[:2] == ["format", "ascii"] or w[:2] == ["format", "binary_big_endian"]:
            raise Unsupported(f"{path}: only binary little-endian PLY is read")
        if w and w[0] == "element":
            elements.append((w[1], int(w[2]), []))
        elif w and w[0] == "property":
            elements[-1][2].append((w[-1], w[1:-1]))
    pos, verts, tris = end, None, None
    for name, count, props in elements:
        if name == "vertex":
            dtype = np.dtype([(p, PLY_TYPES[t[0]]) for p, t in props])
            verts = np.frombuffer(data, dtype, count, pos)
            pos += dtype.itemsize * count
        elif name == "face" and len(props) == 1 and props[0][1][0] == "list":
            ct, it = np.dtype(PLY_TYPES[props[0][1][1]]), np.dtype(PLY_TYPES[props[0][1][2]])
            fast = np.dtype([("n", ct), ("i", it, (3,))])
            f = np.frombuffer(data, fast, count, pos) if pos + fast.itemsize * count <= len(data) else None
            if f is not None and (f["n"] == 3).all():
                tris, pos = f["i"], pos + fast.itemsize * count
            else:  # polygons, points or lines left: xi keeps only the triangles
                keep = []
                for _ in range(count):
                    k = int(np.frombuffer(data, ct, 1, pos)[0])
                    idx = np.frombuffer(data, it, k, pos + ct.itemsize)
                    pos += ct.itemsize + it.itemsize * k
                    if k == 3:
                        keep.append(idx)
                tris = np.array(keep, dtype=np.int64).reshape(-1, 3)
        else:
            raise Unsupported(f"{path}: unexpected PLY element '{name}'")
    xyz = np.stack([verts["x"], verts["y"], verts["z"]], axis=-1).astype(np.float32)
    has_n = all(k in verts.dtype.names for k in ("nx", "ny", "nz"))
    nrm = np.stack([verts["nx"], verts["ny"], verts["nz"]], axis=-1).astype(np.float32) if has_n else None
    return xyz[tris], (nrm[tris] if has_n else None)


def load_mesh(path, tmp):
    """A mesh file through Assimp, as xi loads it (triangulated, node transforms applied): `assimp export` to
    a binary PLY, the same importer for every format, so the triangles are xi's. Exports are kept in
    MESH_CACHE by the file's content hash, so a machine without the tool (a lent GPU) can use exports made
    here."""
    import hashlib
    out = MESH_CACHE / f"{hashlib.sha256(Path(path).read_bytes()).hexdigest()[:20]}.ply"
    if out.exists():
        return read_ply(out)
    part = Path(tmp) / f"assimp-{len(list(Path(tmp).glob('assimp-*')))}.ply"
    try:
        r = subprocess.run(["assimp", "export", str(path), str(part), "-fplyb", "-ptv", "-tri"],
                           capture_output=True, text=True)
    except FileNotFoundError:
        raise Unsupported("mesh files need the `assimp` tool (Debian's assimp-utils; bench/setup-mitsuba.sh)")
    if r.returncode != 0 or not part.exists():
        raise Unsupported(f"assimp export {path} failed:\n{r.stdout}{r.stderr}")
    MESH_CACHE.mkdir(parents=True, exist_ok=True)
    shutil.move(part, out)
    return read_ply(out)


def write_ply(path, v, n):
    """A triangle soup (3 vertices per triangle, as xi stores them) as a binary PLY."""
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


def shape_triangles(shape, base, tmp):
    """One xi shape as triangles (k,3,3) float32 and vertex normals (or None), as xi's read_shape makes them.
    Mesh triangles are split by whether their normals are usable, so returns a list of (v, n)."""
    import numpy as np
    kind = shape["type"]
    if kind in ("quad", "triangle"):
        q = np.array(shape["vertices"], np.float32)
        v, n = q[np.array([[0, 1, 2], [0, 2, 3]] if kind == "quad" else [[0, 1, 2]])], None
    elif kind == "sphere":
        n = icosphere(shape.get("subdivisions", 4))
        v = np.array(shape["center"], np.float32) + np.float32(shape["radius"]) * n
    elif kind == "mesh":
        v, n = load_mesh(Path(base) / shape["file"], tmp)
    else:
        raise Unsupported(f"shape type '{kind}'")
    v, n = transform(xi_matrix(shape.get("transform")), v, n)
    if kind != "mesh":
        return [(v, n)]
    # xi drops degenerate triangles of meshes (zero area up to float noise) and uses flat normals for the
    # triangles whose normals are missing or not finite.
    e1, e2 = (v[:, 1] - v[:, 0]).astype(np.float64), (v[:, 2] - v[:, 0]).astype(np.float64)
    keep = np.linalg.norm(np.cross(e1, e2), axis=1) > 1e-6 * np.maximum((e1 * e1).sum(1), (e2 * e2).sum(1))
    if n is None:
        return [(v[keep], None)]
    good = np.isfinite(n).all(axis=(1, 2))
    return [(v[keep & good], n[keep & good]), (v[keep & ~good], None)]


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


def convert(scene_file, width, height, max_depth, sampler, tmp):
    """xi's JSON scene as a Mitsuba scene dict. Geometry goes over as xi's own triangles (quads split as xi
    splits them, spheres as xi's icospheres with exact vertex normals, meshes through Assimp), one PLY per
    material; the camera as a perspective (or thin-lens) sensor with the same vertical fov."""
    import mitsuba as mi
    import numpy as np
    s = json.loads(Path(scene_file).read_text())
    cam = s["camera"]
    pos, look = np.array(cam["position"], float), np.array(cam["look_at"], float)
    dist = float(np.linalg.norm(look - pos))
    fov = cam.get("fov") or math.degrees(2 * math.atan(cam["film_height_mm"] / 2 / cam["focal_length_mm"]))
    # Mitsuba's look_at puts camera +x at cross(up, forward), so the image's x axis is cross(forward, up),
    # as in xi. Clip planes: xi has none; these keep Mitsuba's default near/far ratio (1e6) at the scene's scale.
    sensor = {"type": "perspective", "fov": fov, "fov_axis": "y",
              "to_world": mi.ScalarTransform4f().look_at(origin=cam["position"], target=cam["look_at"], up=cam["up"]),
              "near_clip": 1e-3 * dist, "far_clip": 1e3 * dist,
              "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                       "pixel_format": "rgb", "component_format": "float32"},
              "sampler": {"type": sampler, "sample_count": 1}}  # (mi.render sets the spp)
    if cam.get("aperture_radius", 0) > 0:
        sensor.update(type="thinlens", aperture_radius=cam["aperture_radius"],
                      focus_distance=cam.get("focus_distance", dist))
    d = {"type": "scene", "sensor": sensor,
         # xi counts bounces (1 = direct light), Mitsuba path vertices (2 = direct light)
         "integrator": {"type": "path", "max_depth": max_depth + 1}}
    bg = s.get("background", [0, 0, 0])
    if max(bg) > 0:  # xi adds it to escaping rays; Mitsuba also samples it as a light: same expectation
        d["background"] = {"type": "constant", "radiance": rgb(bg)}

    groups = {}  # (material, has normals) -> lists of triangles and normals
    for shape in s["shapes"]:
        for v, n in shape_triangles(shape, Path(scene_file).parent, tmp):
            if len(v):
                g = groups.setdefault((shape["material"], n is not None), ([], []))
                g[0].append(v)
                g[1].append(n)
    triangles = 0
    for i, ((mat, has_n), (vs, ns)) in enumerate(sorted(groups.items())):
        path = Path(tmp) / f"shape-{i}.ply"
        v = np.concatenate(vs)
        write_ply(path, v, np.concatenate(ns) if has_n else None)
        triangles += len(v)
        b, emitter = bsdf(s["materials"][mat])
        # face_normals: without it Mitsuba would smooth the normals of a mesh that has none
        d[f"shape-{i}"] = {"type": "ply", "filename": str(path), "face_normals": not has_n, "bsdf": b}
        if emitter:
            d[f"shape-{i}"]["emitter"] = emitter
    return d, triangles


def read_rgb(path):
    """The R,G,B layer of an EXR (xi's has more layers) and, if present, its variance layer."""
    import mitsuba as mi
    import numpy as np
    layers = dict(mi.Bitmap(str(path)).split())
    var = layers.get("variance")
    return np.array(layers["<root>"], np.float64), (None if var is None else np.array(var, np.float64))


def worker(variant):
    """Answers one JSON line per request on stdin: hello, load, render, compare."""
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # whatever Mitsuba prints goes to stderr, not into the replies
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    mi.set_variant(variant)
    mi.set_log_level(mi.LogLevel.Warn)
    scene = None
    for line in sys.stdin:
        req = json.loads(line)
        cmd = req["cmd"]
        try:
            if cmd == "hello":
                res = dict(version=mi.__version__, variant=variant, threads=dr.thread_count())
            elif cmd == "load":
                scene = None
                d, triangles = convert(req["scene"], req["width"], req["height"], req["max_depth"], req["sampler"],
                                       req["tmp"])
                scene = mi.load_dict(d)
                res = dict(triangles=triangles)
            elif cmd == "render":
                t0 = time.perf_counter()
                img = mi.render(scene, spp=req["spp"], seed=req["seed"])
                pixels = np.array(img)  # forces the evaluation: Dr.Jit is lazy
                seconds = time.perf_counter() - t0
                if req.get("out"):  # (write_async=True, the default, deadlocks here)
                    mi.util.write_bitmap(req["out"], pixels, write_async=False)
                    mi.util.write_bitmap(str(Path(req["out"]).with_suffix(".png")), pixels, write_async=False)
                res = dict(seconds=seconds, mean=pixels.mean(axis=(0, 1)).tolist())
            elif cmd == "compare":
                xi_rgb, xi_var = read_rgb(req["xi"])
                mi_rgb, _ = read_rgb(req["mitsuba"])

                def relmse(a, r):  # xi diff's relmse
                    return float(((a - r) ** 2 / (r ** 2 + 0.01)).mean())
                npix = xi_rgb.shape[0] * xi_rgb.shape[1]
                res = dict(xi=xi_rgb.mean(axis=(0, 1)).tolist(), mitsuba=mi_rgb.mean(axis=(0, 1)).tolist(),
                           xi_se=(np.sqrt(xi_var.sum(axis=(0, 1))) / npix).tolist() if xi_var is not None else None,
                           relmse=relmse(mi_rgb, xi_rgb), relmse_mirrored=relmse(mi_rgb[:, ::-1], xi_rgb),
                           relmse_flipped=relmse(mi_rgb[::-1], xi_rgb))
            else:
                raise ValueError(f"unknown request {cmd}")
        except Unsupported as e:
            res = dict(unsupported=str(e))
        reply.write(json.dumps(res) + "\n")


# ---------------------------------------------------------------------------------------------------------
# Driver side: Debian's /usr/bin/python3, standard library only.

def libllvm():
    """libLLVM 19 from Debian's libllvm19, for Dr.Jit's LLVM backend."""
    r = subprocess.run(["dpkg", "-L", "libllvm19"], capture_output=True, text=True)
    found = [p for p in r.stdout.split() if re.search(r"/libLLVM(-19)?\.so(\.[\d.]+)?$", p)]
    if not found:
        sys.exit("bench: libLLVM 19 is missing: run bash bench/setup-mitsuba.sh (or set DRJIT_LIBLLVM_PATH)")
    return found[0]


class Mitsuba:
    """The Mitsuba worker: this file run by the venv's python with --worker, kept for the whole run so that
    Dr.Jit's compiled kernels stay in memory between the warm-up and the timed renders."""

    def __init__(self, venv, variant, timeout):
        self.timeout = timeout
        python = Path(venv) / "bin" / "python"
        if not python.exists():
            sys.exit(f"bench: no Mitsuba venv at {venv}: run bash bench/setup-mitsuba.sh")
        env = dict(os.environ)
        if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in env:
            env["DRJIT_LIBLLVM_PATH"] = libllvm()
        self.proc = subprocess.Popen([python, __file__, "--worker", "--mitsuba-variant", variant],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        self.info = self.ask(cmd="hello")

    def ask(self, **req):
        """One request and its reply. A worker that does not answer within the timeout (a GPU driver that
        never returns, say) is stopped with an error naming the request, so the bench never hangs."""
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        if not select.select([self.proc.stdout], [], [], self.timeout)[0]:
            self.proc.kill()
            sys.exit(f"bench: the Mitsuba worker gave no answer to '{req['cmd']}' in {self.timeout:g} s "
                     f"(--worker-timeout); its messages, if any, are above")
        line = self.proc.stdout.readline()
        if not line:
            sys.exit(f"bench: the Mitsuba worker stopped (exit status {self.proc.wait()}; its messages are above)")
        return json.loads(line)

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def scene_depth(scene):
    return json.loads(Path(scene).read_text()).get("render", {}).get("max_depth", 8)


def load(a, mitsuba, scene, resolution, depth, tmp):
    """Loads SCENE into the worker; returns False (after saying why) if Mitsuba cannot render it."""
    w, h = c.parse_resolution(resolution)
    t0 = time.monotonic()
    r = mitsuba.ask(cmd="load", scene=str(scene), width=w, height=h, max_depth=depth, sampler=a.mitsuba_sampler,
                    tmp=str(tmp))
    if "unsupported" in r:
        print(f"mitsuba: skipping {scene.stem}: unsupported: {r['unsupported']}", file=sys.stderr)
        return False
    print(f"mitsuba: {scene.stem}: {r['triangles']} triangles, loaded in {time.monotonic() - t0:.1f} s",
          file=sys.stderr)
    return True


def xi_render(a, xi, scene, out, spp, seed, resolution):
    return c.render(xi, scene, out, spp, seed=seed, resolution=resolution, sampler=a.xi_sampler,
                    device=a.xi_device, max_depth=a.max_depth)


def measure(a, xi, mitsuba, scene, resolution, tmp):
    """Timed runs of both renderers on one scene (plus relMSE with --error): one result row."""
    name, depth = scene.stem, a.max_depth or scene_depth(scene)
    w, h = c.parse_resolution(resolution)
    samples = w * h * a.spp
    ok = load(a, mitsuba, scene, resolution, depth, tmp)
    ref = None
    if a.error:
        default_depth = a.max_depth is None or a.max_depth == scene_depth(scene)
        ref = c.reference(xi, scene, resolution, a.ref_spp, log=lambda m: print(m, file=sys.stderr),
                          max_depth=None if default_depth else a.max_depth)
    if ok:  # Dr.Jit compiles its kernels for this spp here, untimed (seed 0: timed runs use 1, 2, ...)
        mitsuba.ask(cmd="render", spp=a.spp, seed=0)
    runs = {"xi": [], "mitsuba": []}
    for i in range(a.runs):
        for who in ("xi", "mitsuba")[::1 if i % 2 == 0 else -1]:  # alternate which goes first
            out = Path(tmp) / f"{name}-{who}.exr"
            if who == "xi":  # (common.render warms xi up once, untimed: kernel build and PoCL's compiles)
                seconds = xi_render(a, xi, scene, out, a.spp, i + 1, resolution)["seconds"]
            elif ok:
                seconds = mitsuba.ask(cmd="render", spp=a.spp, seed=i + 1, out=str(out) if ref else None)["seconds"]
            else:
                continue
            runs[who].append((seconds, c.diff(xi, out, ref, "relmse") if ref else math.nan))
    row = dict(scene=name, resolution=resolution, spp=a.spp, max_depth=depth, runs=a.runs)
    for who, rs in runs.items():
        sec = c.median([r[0] for r in rs]) if rs else math.nan
        err = c.median([r[1] for r in rs]) if rs else math.nan
        row.update({f"{who}_s": sec, f"{who}_msamples": samples / sec * 1e-6 if rs else math.nan,
                    f"{who}_relmse": err, f"{who}_eff": 1 / (err * sec) if rs and ref else math.nan})
    row["time_ratio"] = row["xi_s"] / row["mitsuba_s"]  # same samples on both: time per sample
    row["eff_ratio"] = row["xi_eff"] / row["mitsuba_eff"]
    return row


def check(a, xi, mitsuba, scene, resolution, out_dir, tmp):
    """Mean radiance per channel of both renderers at RESOLUTION with --spp: should agree within noise."""
    name, depth = scene.stem, a.max_depth or scene_depth(scene)
    if not load(a, mitsuba, scene, resolution, depth, tmp):
        return []
    xi_out, mi_out = out_dir / f"peers-check-{name}-xi.exr", out_dir / f"peers-check-{name}-mitsuba.exr"
    t_xi = xi_render(a, xi, scene, xi_out, a.spp, 1, resolution)["seconds"]
    t_mi = mitsuba.ask(cmd="render", spp=a.spp, seed=1, out=str(mi_out))["seconds"]
    r = mitsuba.ask(cmd="compare", xi=str(xi_out), mitsuba=str(mi_out))
    print(f"\n{name}, {resolution}, {a.spp} spp, xi max depth {depth}: xi {t_xi:.2f} s, Mitsuba {t_mi:.2f} s "
          f"(its kernel compilation included); images {xi_out.relative_to(c.ROOT)} and {mi_out.name}")
    rows = []
    for k, ch in enumerate("RGB"):
        x, m = r["xi"][k], r["mitsuba"][k]
        # 2 sigma of the ratio, from xi's standard error of the mean, taking Mitsuba's noise as alike
        tol = 2 * math.sqrt(2) * r["xi_se"][k] / x if r["xi_se"] and x > 0 else math.nan
        rows.append([name, ch, x, m, m / x if x > 0 else math.nan, tol])
    c.print_table(["scene", "channel", "xi mean", "Mitsuba mean", "Mitsuba / xi", "±2σ"],
                  [[n, ch, c.fmt(x, ".5f"), c.fmt(m, ".5f"), c.fmt(q, ".4f"), c.fmt(t, ".4f")]
                   for n, ch, x, m, q, t in rows])
    print(f"relMSE of Mitsuba's image against xi's: {r['relmse']:.3e} as rendered, {r['relmse_mirrored']:.3e} "
          f"mirrored left-right, {r['relmse_flipped']:.3e} flipped upside down (as rendered should be smallest, "
          f"or about equal for a symmetric scene)")
    if min(r["relmse_mirrored"], r["relmse_flipped"]) < 0.5 * r["relmse"]:
        print("WARNING: a mirrored image matches far better: the camera conversion is wrong")
    return [row + [r["relmse"]] for row in rows]


CEILING = re.compile(r"^(camera|bounce) rays\s+(\d+) rays\s+xi extend\s+([\d.]+) Mrays/s\s+embree\s+([\d.]+) "
                     r"Mrays/s\s+ratio ([\d.]+)\s+same hit ([\d.]+)%\n\s+embree rtcIntersect16\s+([\d.]+) Mrays/s",
                     re.M)


def ceiling(a, xi, scenes, resolution, out_dir):
    """bench/ceiling.cpp (xi's extend kernel against Embree's rtcIntersect1 on the same rays), if built."""
    tool = Path(a.ceiling) if a.ceiling else xi.parent / "bench" / "xi_ceiling"
    if not os.access(tool, os.X_OK):
        print(f"\nembree: no {tool}: configure with -DXI_WITH_EMBREE=ON (Debian's libembree-dev) and build "
              f"the xi_ceiling target")
        return
    rows = []
    for scene in scenes:
        text = c.run([tool, scene, a.runs, resolution])
        for m in CEILING.finditer(text):
            rows.append([scene.stem, resolution, m[1], int(m[2]), float(m[3]), float(m[4]), float(m[5]),
                         float(m[6]), float(m[7]), float(m[3]) / float(m[7])])
    headers = ["scene", "resolution", "rays", "count", "xi extend Mrays/s", "Embree Mrays/s", "xi / Embree",
               "same hit %", "Embree x16 Mrays/s", "xi / x16"]
    print(f"\nThe ceiling: xi's extend kernel against Embree's rtcIntersect1 on the same rays, and its "
          f"rtcIntersect16 on packets of 16 (as Mitsuba's LLVM variant calls it) ({tool.name}, medians of {a.runs}; "
          f"ratio > 1: xi is faster)")
    c.print_table(headers, [[s, r, k, n, c.fmt(x, ".2f"), c.fmt(e, ".2f"), c.fmt(q, ".3f"), c.fmt(h, ".2f"),
                             c.fmt(e16, ".2f"), c.fmt(q16, ".3f")] for s, r, k, n, x, e, q, h, e16, q16 in rows])
    c.write_csv(out_dir / "peers-embree.csv", headers, rows)


def main():
    p = c.parser(__doc__)
    p.add_argument("--scenes", type=c.str_list, default=DEFAULT_SCENES,
                   help="comma-separated: names in scenes/ or paths to xi scene files")
    p.add_argument("--resolution", help="default 512x512; 256x256 with --error; 64x64 with --check")
    p.add_argument("--spp", type=int, help="default 64; 1024 with --check")
    p.add_argument("--max-depth", type=int, help="xi's bounces (Mitsuba gets one more); default: the scene's")
    p.add_argument("--runs", type=int, default=3, help="timed runs of each renderer, interleaved; medians")
    p.add_argument("--error", action="store_true", help="also relMSE against an xi reference, and efficiency")
    p.add_argument("--ref-spp", type=int, default=4096, help="spp of the --error reference (cached in bench/refs)")
    p.add_argument("--check", action="store_true", help="only compare mean radiance (is the conversion right?)")
    p.add_argument("--xi-device", help="xi's --device")
    p.add_argument("--xi-sampler", default="random",
                   help="xi's sampler; random matches Mitsuba's independent sampler (xi's default is sobol)")
    p.add_argument("--mitsuba-variant", default="llvm_ad_rgb", help="cuda_ad_rgb on an NVIDIA GPU")
    p.add_argument("--mitsuba-sampler", default="independent", choices=sorted(MITSUBA_SAMPLERS),
                   help="Mitsuba's sampler (independent matches xi's random; ldsampler is its low-discrepancy one, "
                        "stratified and multijitter its stratified ones, to set against xi's sobol or stratified)")
    p.add_argument("--venv", default=str(VENV), help="the venv with Mitsuba (bench/setup-mitsuba.sh)")
    p.add_argument("--worker-timeout", type=float, default=600,
                   help="seconds the Mitsuba worker may take to answer one request (start, load, render)")
    p.add_argument("--embree", action="store_true", help="also run the Embree ceiling tool, if built")
    p.add_argument("--ceiling", help="the xi_ceiling program (default: bench/xi_ceiling beside --xi)")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.worker:
        return worker(a.mitsuba_variant)
    a.spp = a.spp or (1024 if a.check else 64)
    if not MITSUBA_SAMPLERS[a.mitsuba_sampler](a.spp):  # Mitsuba would round the spp and time other work
        p.error(f"--mitsuba-sampler {a.mitsuba_sampler} takes {MITSUBA_SAMPLER_SPP[a.mitsuba_sampler]}, "
                f"not --spp {a.spp}")
    resolution = a.resolution or ("64x64" if a.check else "256x256" if a.error else "512x512")
    xi, out_dir = c.find_xi(a.xi), Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    scenes = [Path(c.scene_path(s)) for s in a.scenes]
    mitsuba = Mitsuba(a.venv, a.mitsuba_variant, a.worker_timeout)
    info = mitsuba.info
    print(f"xi: {xi} ({c.machine(xi)}; device {a.xi_device or 'default'}, {a.xi_sampler} sampler); "
          f"Mitsuba {info['version']} {info['variant']}, {a.mitsuba_sampler} sampler, {info['threads']} threads",
          file=sys.stderr)

    with tempfile.TemporaryDirectory(prefix="xi-peers-") as tmp:
        if a.check:
            rows = []
            for scene in scenes:
                rows += check(a, xi, mitsuba, scene, resolution, out_dir, tmp)
            c.write_csv(out_dir / "peers-check.csv",
                        ["scene", "channel", "xi_mean", "mitsuba_mean", "ratio", "tolerance_2sigma",
                         "relmse_mitsuba_vs_xi"], rows)
            mitsuba.close()
            return
        rows = [measure(a, xi, mitsuba, scene, resolution, tmp) for scene in scenes]
    mitsuba.close()

    headers = ["scene", "resolution", "spp", "depth", "xi s", "xi Ms/s", "Mitsuba s", "Mitsuba Ms/s", "xi/Mitsuba"]
    table = [[r["scene"], r["resolution"], r["spp"], r["max_depth"], c.fmt(r["xi_s"], ".3f"),
              c.fmt(r["xi_msamples"], ".3f"), c.fmt(r["mitsuba_s"], ".3f"), c.fmt(r["mitsuba_msamples"], ".3f"),
              c.fmt(r["time_ratio"], ".3f")] for r in rows]
    if a.error:
        headers += ["xi relMSE", "Mitsuba relMSE", "xi eff", "Mitsuba eff", "eff xi/Mitsuba"]
        for t, r in zip(table, rows):
            t += [c.fmt(r["xi_relmse"], ".3e"), c.fmt(r["mitsuba_relmse"], ".3e"), c.fmt(r["xi_eff"], ".4g"),
                  c.fmt(r["mitsuba_eff"], ".4g"), c.fmt(r["eff_ratio"], ".3f")]
    print(f"\nxi against Mitsuba {info['version']} ({info['variant']}), medians of {a.runs} interleaved runs; "
          f"{c.machine(xi)}")
    c.print_table(headers, table)
    print("depth: xi's max bounces (Mitsuba max_depth = depth + 1). xi/Mitsuba: xi's time per sample over "
          "Mitsuba's (< 1: xi is faster).")
    if a.error:
        print(f"relMSE against an xi reference of {a.ref_spp} spp (bench/refs); eff = 1 / (relMSE x seconds); "
              f"eff xi/Mitsuba > 1: xi reaches a given error sooner.")
    keys = ["scene", "resolution", "spp", "max_depth", "runs", "xi_s", "xi_msamples", "mitsuba_s",
            "mitsuba_msamples", "time_ratio", "xi_relmse", "mitsuba_relmse", "xi_eff", "mitsuba_eff", "eff_ratio"]
    c.write_csv(out_dir / "peers.csv", keys + ["xi_device", "xi_sampler", "mitsuba_variant", "mitsuba_sampler"],
                [[r[k] for k in keys] + [a.xi_device or "default", a.xi_sampler, info["variant"], a.mitsuba_sampler]
                 for r in rows])
    if a.embree:
        ceiling(a, xi, scenes, resolution, out_dir)


if __name__ == "__main__":
    main()
