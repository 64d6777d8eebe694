#!/usr/bin/python3
"""xi against Mitsuba 3 on the same scenes, and optionally against Embree's ray-tracing ceiling.

Speed: `xi render` and Mitsuba 3's `path` integrator render each scene at the same resolution, spp and path
length, alternately, after one untimed warm-up each (kernel compilation excluded on both sides); medians of
--runs. The ratio is xi's time per sample over Mitsuba's (<= 1: xi is faster). --error adds each one's
relMSE against a high-spp xi reference and the efficiency 1/(relMSE x seconds). --check renders both at
64x64 with many spp and compares their mean radiance, to show that the scene conversion is right. --env is
--error on two environment-lit scenes (bench/make_env_scenes.py: a diffuse sphere and floor under the bundled
sky and under a map with a small bright sun) at 64x64, 256 spp, against a 32768-spp reference: the mean
relMSE of the seeds and xi's over Mitsuba's, per map, which is how well each samples the environment.

Mitsuba runs in bench/.venv (made by bench/setup-mitsuba.sh) in a worker process: this file, run by the
venv's python with --worker. It loads each scene through bench/mitsuba_scene.py: xi's camera and materials
from the JSON, xi's own triangles from `xi export`.

--isa avx2 compiles both for an AVX2 CPU (Haswell) on whatever x86 CPU runs the bench, to measure the code
an AVX2 machine runs on an AVX-512 one: PoCL's avx2 kernel library and target, xi with its AVX2 defaults
(16 lanes, packets of 8 rays), Dr.Jit's LLVM backend targeting Haswell with 8-wide vectors: the two
renderers' AVX2 code on the same cores."""
import argparse
import json
import math
import os
import re
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402
import mitsuba_scene as ms  # noqa: E402

DEFAULT_SCENES = ["cornell-box", "bench/scenes/engine.json"]
ENV_SCENES = ["env-sky", "env-sun"]  # --env's (bench/make_env_scenes.py writes them)
# --env's defaults: the resolution, spp, reference spp and seeds its numbers are quoted at.
ENV_DEFAULTS = dict(resolution="64x64", spp=256, ref_spp=32768, runs=3)
VENV = c.ROOT / "bench" / ".venv"
# Mitsuba 3.9.1's samplers and the spp each takes without rounding it (to a square; ldsampler to a power of
# four, at least 4).
MITSUBA_SAMPLERS = {"independent": lambda n: n > 0,
                    "stratified": lambda n: n > 0 and math.isqrt(n) ** 2 == n,
                    "multijitter": lambda n: n > 0 and math.isqrt(n) ** 2 == n,
                    "ldsampler": lambda n: n > 0 and n & (n - 1) == 0 and n.bit_length() % 2 == 1 and n >= 4}
MITSUBA_SAMPLER_SPP = {"independent": "any spp", "stratified": "a square spp", "multijitter": "a square spp",
                       "ldsampler": "a power-of-four spp (4, 16, 64, ...)"}


# ---------------------------------------------------------------------------------------------------------
# Worker side: runs under bench/.venv/bin/python with numpy and mitsuba.

def read_rgb(path):
    """The R,G,B layer of an EXR (xi's has more layers) and, if present, its variance layer."""
    import mitsuba as mi
    import numpy as np
    layers = dict(mi.Bitmap(str(path)).split())
    var = layers.get("variance")
    return np.array(layers["<root>"], np.float64), (None if var is None else np.array(var, np.float64))


def time_rays(scene, path, shadow, runs):
    """Mrays/s of the loaded scene's own ray queries on the rays `xi_ceiling --rays-out` wrote to PATH
    (float32 origin xyz, tmax, direction xyz, 0 per ray): ray_intersect_preliminary for closest hits, or
    with SHADOW ray_test up to each ray's tmax; the median of RUNS after a warm-up (Dr.Jit compiles it)."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    a = np.fromfile(path, dtype=np.float32).reshape(-1, 8)
    if not len(a):
        return dict(rays=0, mrays=None, hits=0)
    col = [mi.Float(np.ascontiguousarray(a[:, i])) for i in range(8)]
    maxt = col[3] if shadow else dr.inf
    ray = mi.Ray3f(mi.Point3f(col[0], col[1], col[2]), mi.Vector3f(col[4], col[5], col[6]), maxt, 0.0, [])
    dr.eval(ray)
    seconds = []
    for _ in range(runs + 1):
        t0 = time.perf_counter()
        hit = scene.ray_test(ray) if shadow else scene.ray_intersect_preliminary(ray).is_valid()
        dr.eval(hit)
        dr.sync_thread()  # Dr.Jit launches asynchronously
        seconds.append(time.perf_counter() - t0)
    seconds = sorted(seconds[1:])
    return dict(rays=len(a), mrays=len(a) / seconds[len(seconds) // 2] * 1e-6,
                hits=int(np.count_nonzero(np.array(hit))))


def set_llvm_target(dr, target):
    """Dr.Jit's LLVM backend compiles for TARGET ('cpu:features:vector width') from here on. Its Python module
    does not expose this; the C++ function is in libdrjit-core.so."""
    import ctypes
    cpu, features, width = target.split(":")
    core = ctypes.CDLL(str(Path(dr.__file__).parent / "libdrjit-core.so"))
    set_target = core._Z19jit_llvm_set_targetPKcS0_j  # jit_llvm_set_target(const char*, const char*, uint32_t)
    set_target.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    set_target(cpu.encode(), features.encode(), int(width))
    get_cpu, get_width = core._Z19jit_llvm_target_cpuv, core._Z21jit_llvm_vector_widthv
    get_cpu.restype, get_width.restype = ctypes.c_char_p, ctypes.c_uint32
    return f"{get_cpu().decode()}, {get_width()}-wide"


def worker(variant, llvm_target):
    """Answers one JSON line per request on stdin: hello, load, render, compare, rays."""
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # whatever Mitsuba prints goes to stderr, not into the replies
    import drjit as dr
    target = set_llvm_target(dr, llvm_target) if llvm_target else None
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
                res = dict(version=mi.__version__, variant=variant + (f" ({target})" if target else ""),
                           threads=dr.thread_count())
            elif cmd == "load":
                scene = None
                d, triangles = ms.convert(req["scene"], req["export"], req["width"], req["height"],
                                          req["max_depth"], req["sampler"])
                scene = mi.load_dict(d)
                res = dict(triangles=triangles)
            elif cmd == "render":
                t0 = time.perf_counter()
                img = mi.render(scene, spp=req["spp"], seed=req["seed"])
                pixels = np.array(img)  # forces the evaluation: Dr.Jit is lazy
                seconds = time.perf_counter() - t0
                if (req.get("out") or "").endswith(".npy"):  # the pixels alone: Mitsuba's EXR is PIZ, which
                    # bench/exr.py does not read
                    np.save(req["out"], pixels.astype(np.float32))
                elif req.get("out"):  # (write_async=True, the default, deadlocks here)
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
            elif cmd == "rays":
                res = time_rays(scene, req["file"], req["shadow"], req["runs"])
            else:
                raise ValueError(f"unknown request {cmd}")
        except ms.Unsupported as e:
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

    def __init__(self, venv, variant, timeout, llvm_target=None):
        self.timeout = timeout
        python = Path(venv) / "bin" / "python"
        if not python.exists():
            sys.exit(f"bench: no Mitsuba venv at {venv}: run bash bench/setup-mitsuba.sh")
        env = dict(os.environ)
        if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in env:
            env["DRJIT_LIBLLVM_PATH"] = libllvm()
        cmd = [python, __file__, "--worker", "--mitsuba-variant", variant]
        if llvm_target:
            cmd += ["--llvm-target", llvm_target]
        self.proc = subprocess.Popen(cmd,
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


def load(a, xi, mitsuba, scene, resolution, depth, tmp):
    """Loads SCENE into the worker, with xi's triangles from `xi export`; returns False (after saying why)
    if Mitsuba cannot render it."""
    w, h = c.parse_resolution(resolution)
    t0 = time.monotonic()
    export = Path(tmp) / f"export-{scene.stem}-{len(list(Path(tmp).glob('export-*')))}"
    try:
        ms.export(xi, scene, export)
        r = mitsuba.ask(cmd="load", scene=str(scene), export=str(export), width=w, height=h, max_depth=depth,
                        sampler=a.mitsuba_sampler)
    except ms.Unsupported as e:
        r = dict(unsupported=str(e))
    if "unsupported" in r:
        print(f"mitsuba: skipping {scene.stem}: unsupported: {r['unsupported']}", file=sys.stderr)
        return False
    print(f"mitsuba: {scene.stem}: {r['triangles']} triangles, loaded in {time.monotonic() - t0:.1f} s",
          file=sys.stderr)
    return True


def xi_render(a, xi, scene, out, spp, seed, resolution):
    return c.render(xi, scene, out, spp, seed=seed, resolution=resolution, sampler=a.xi_sampler,
                    device=a.xi_device, max_depth=a.max_depth, args=a.xi_args)


def measure(a, xi, mitsuba, scene, resolution, tmp):
    """Timed runs of both renderers on one scene (plus relMSE with --error): one result row."""
    name, depth = scene.stem, a.max_depth or scene_depth(scene)
    w, h = c.parse_resolution(resolution)
    samples = w * h * a.spp
    ok = load(a, xi, mitsuba, scene, resolution, depth, tmp)
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
        row[f"{who}_relmse_mean"] = sum(r[1] for r in rs) / len(rs) if rs else math.nan
        row.update({f"{who}_s": sec, f"{who}_msamples": samples / sec * 1e-6 if rs else math.nan,
                    f"{who}_relmse": err, f"{who}_eff": 1 / (err * sec) if rs and ref else math.nan})
    row["time_ratio"] = row["xi_s"] / row["mitsuba_s"]  # same samples on both: time per sample
    row["eff_ratio"] = row["xi_eff"] / row["mitsuba_eff"]
    return row


def check(a, xi, mitsuba, scene, resolution, out_dir, tmp):
    """Mean radiance per channel of both renderers at RESOLUTION with --spp: should agree within noise."""
    name, depth = scene.stem, a.max_depth or scene_depth(scene)
    if not load(a, xi, mitsuba, scene, resolution, depth, tmp):
        return []
    xi_out, mi_out = out_dir / f"peers-check-{name}-xi.exr", out_dir / f"peers-check-{name}-mitsuba.exr"
    t_xi = xi_render(a, xi, scene, xi_out, a.spp, 1, resolution)["seconds"]
    t_mi = mitsuba.ask(cmd="render", spp=a.spp, seed=1, out=str(mi_out))["seconds"]
    r = mitsuba.ask(cmd="compare", xi=str(xi_out), mitsuba=str(mi_out))
    full = xi_out.resolve()
    shown = full.relative_to(c.ROOT) if full.is_relative_to(c.ROOT) else full  # (--out may lie elsewhere)
    print(f"\n{name}, {resolution}, {a.spp} spp, xi max depth {depth}: xi {t_xi:.2f} s, Mitsuba {t_mi:.2f} s "
          f"(its kernel compilation included); images {shown} and {mi_out.name}")
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


CEILING = re.compile(r"^(camera rays|bounce rays \d|shadow rays \d)\s+(\d+) rays\s+xi\s+([\d.]+) Mrays/s "
                     r"\(([a-z ]+)\)\s+embree\s+([\d.]+) Mrays/s\s+embree x16\s+([\d.]+) Mrays/s\s+"
                     r"same ([\d.]+)%\s+hits (\d+)", re.M)


def ceiling_rays_file(row):
    """The file `xi_ceiling --rays-out` writes a row's rays to: camera.f32, bounce1.f32, shadow0.f32, ..."""
    return "camera.f32" if row == "camera rays" else row.split()[0] + row.split()[-1] + ".f32"


# Samples of every pixel in the one wave the ceiling records: as many as a 512x512 render's waves hold.
CEILING_SPP = 4


def ceiling(a, xi, mitsuba, scenes, resolution, out_dir, tmp):
    """bench/ceiling.cpp (xi's extend and shadow kernels against Embree on the same rays), if built, and
    Mitsuba's own ray queries on those rays."""
    tool = Path(a.ceiling) if a.ceiling else xi.parent / "bench" / "xi_ceiling"
    if not os.access(tool, os.X_OK):
        print(f"\nembree: no {tool}: configure with -DXI_WITH_EMBREE=ON (Debian's libembree-dev) and build "
              f"the xi_ceiling target")
        return
    rows = []
    for scene in scenes:
        rays_dir = Path(tmp) / f"rays-{scene.stem}"
        text = c.run([tool, scene, a.runs, resolution, "--spp", CEILING_SPP, "--rays-out", rays_dir])
        loaded = load(a, xi, mitsuba, scene, resolution, scene_depth(scene), tmp)
        for m in CEILING.finditer(text):
            mi_rate = mi_hits = None
            if loaded:
                r = mitsuba.ask(cmd="rays", file=str(rays_dir / ceiling_rays_file(m[1])),
                                shadow=m[1].startswith("shadow"), runs=a.runs)
                mi_rate, mi_hits = r.get("mrays"), r.get("hits")
            xi_rate, em, em16 = float(m[3]), float(m[5]), float(m[6])
            rows.append([scene.stem, resolution, m[1], int(m[2]), m[4], xi_rate, em, xi_rate / em, em16, xi_rate / em16,
                         mi_rate, xi_rate / mi_rate if mi_rate else None, float(m[7]), int(m[8]), mi_hits])
    headers = ["scene", "resolution", "rays", "count", "xi traces them", "xi Mrays/s", "Embree Mrays/s", "xi / Embree",
               "Embree x16 Mrays/s", "xi / x16", "Mitsuba Mrays/s", "xi / Mitsuba", "same %", "xi hits", "Mitsuba hits"]
    print(f"\nThe ceiling: xi's extend and shadow kernels on rays recorded from one wave of a render ({CEILING_SPP} samples of every pixel), against Embree's "
          f"rtcIntersect1/rtcOccluded1, its 16-ray packets (as Mitsuba's LLVM variant calls it) and Mitsuba's own "
          f"ray_intersect_preliminary/ray_test on the same rays ({tool.name}, medians of {a.runs}; ratio > 1: xi is "
          f"faster; same: xi's and Embree's answers agree; hits: the rays that hit something, a shadow ray: occluded, "
          f"by xi and by Mitsuba, which should agree but for ties at shared edges)")
    c.print_table(headers, [[s, r, k, n, how, c.fmt(x, ".2f"), c.fmt(e, ".2f"), c.fmt(q, ".3f"), c.fmt(e16, ".2f"),
                             c.fmt(q16, ".3f"), c.fmt(m, ".2f"), c.fmt(qm, ".3f"), c.fmt(same, ".3f"), xh,
                             c.fmt(mh, "d")]
                            for s, r, k, n, how, x, e, q, e16, q16, m, qm, same, xh, mh in rows])
    c.write_csv(out_dir / "peers-embree.csv", headers, rows)


def main():
    p = c.parser(__doc__)
    p.add_argument("--scenes", type=c.str_list, default=DEFAULT_SCENES,
                   help="comma-separated: names in scenes/ or of the bench's own (engine, material, product, "
                        "product-sky, textured in bench/scenes/), or paths to xi scene files")
    p.add_argument("--resolution", help="default 512x512; 256x256 with --error; 64x64 with --check")
    p.add_argument("--spp", type=int, help="default 64; 1024 with --check")
    p.add_argument("--max-depth", type=int, help="xi's bounces (Mitsuba gets one more); default: the scene's")
    p.add_argument("--runs", type=int, help="timed runs of each renderer, interleaved; medians (default 3)")
    p.add_argument("--error", action="store_true", help="also relMSE against an xi reference, and efficiency")
    p.add_argument("--ref-spp", type=int, help="spp of the --error reference (cached in bench/refs; default 4096, "
                                              "32768 with --env)")
    p.add_argument("--refs", default=str(c.REFS), help="folder of the cached references")
    p.add_argument("--env", action="store_true",
                   help="--error on the environment-lit scenes env-sky and env-sun (written if missing), by default "
                        "at 64x64, 256 spp, a 32768-spp reference, 3 seeds; prints the mean relMSE xi/Mitsuba per map")
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
    p.add_argument("--isa", choices=sorted(c.ISAS),
                   help="compile both renderers for this instruction set instead of this CPU's (see above)")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--llvm-target", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.worker:
        return worker(a.mitsuba_variant, a.llvm_target)
    isa = c.ISAS.get(a.isa, {})
    if isa:
        if not a.mitsuba_variant.startswith("llvm"):
            p.error("--isa is for CPUs: it needs an llvm_* --mitsuba-variant")
        os.environ["POCL_KERNELLIB_NAME"] = isa["pocl_kernellib"]  # read by every xi this script runs
    a.xi_args = isa.get("xi_args", [])
    if a.env:
        a.error = True
        for key, value in ENV_DEFAULTS.items():
            if getattr(a, key) is None:
                setattr(a, key, value)
        if a.scenes == DEFAULT_SCENES:
            a.scenes = ENV_SCENES
        if any(not (c.ROOT / c.BENCH_SCENES[s]).exists() for s in ENV_SCENES if s in a.scenes):
            import make_env_scenes
            make_env_scenes.write()
    a.runs, a.ref_spp = a.runs or 3, a.ref_spp or 4096
    c.REFS = Path(a.refs).resolve()
    a.spp = a.spp or (1024 if a.check else 64)
    if not MITSUBA_SAMPLERS[a.mitsuba_sampler](a.spp):  # Mitsuba would round the spp and time other work
        p.error(f"--mitsuba-sampler {a.mitsuba_sampler} takes {MITSUBA_SAMPLER_SPP[a.mitsuba_sampler]}, "
                f"not --spp {a.spp}")
    resolution = a.resolution or ("64x64" if a.check else "256x256" if a.error else "512x512")
    xi, out_dir = c.find_xi(a.xi), Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    scenes = [Path(c.scene_path(s)) for s in a.scenes]
    mitsuba = Mitsuba(a.venv, a.mitsuba_variant, a.worker_timeout, isa.get("llvm_target"))
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
        print_rows(a, info, xi, rows, out_dir)
        if a.env:
            print_env(a, info, rows, out_dir)
        if a.embree:
            ceiling(a, xi, mitsuba, scenes, resolution, out_dir, tmp)
    mitsuba.close()


def print_rows(a, info, xi, rows, out_dir):
    """The speed (and --error) table, printed and written to peers.csv."""
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
        print(f"relMSE against an xi reference of {a.ref_spp} spp ({c.shown(c.REFS)}); eff = 1 / (relMSE x seconds); "
              f"eff xi/Mitsuba > 1: xi reaches a given error sooner.")
    keys = ["scene", "resolution", "spp", "max_depth", "runs", "xi_s", "xi_msamples", "mitsuba_s",
            "mitsuba_msamples", "time_ratio", "xi_relmse", "mitsuba_relmse", "xi_eff", "mitsuba_eff", "eff_ratio"]
    c.write_csv(out_dir / "peers.csv", keys + ["xi_device", "xi_sampler", "mitsuba_variant", "mitsuba_sampler"],
                [[r[k] for k in keys] + [a.xi_device or "default", a.xi_sampler, info["variant"], a.mitsuba_sampler]
                 for r in rows])


def print_env(a, info, rows, out_dir):
    """--env: per map the mean relMSE of the seeds and xi's over Mitsuba's, printed and in peers-env.csv."""
    table = [[r["scene"], r["resolution"], r["spp"], r["runs"], r["xi_relmse_mean"], r["mitsuba_relmse_mean"],
              r["xi_relmse_mean"] / r["mitsuba_relmse_mean"] if r["mitsuba_relmse_mean"] > 0 else math.nan]
             for r in rows]
    print(f"\nEnvironment light: mean relMSE of {a.runs} seeds against a {a.ref_spp}-spp xi reference; xi "
          f"{a.xi_sampler} sampler, Mitsuba {info['version']} {a.mitsuba_sampler} sampler, the same spp")
    c.print_table(["scene", "resolution", "spp", "seeds", "xi relMSE", "Mitsuba relMSE", "xi/Mitsuba"],
                  [[s, r, n, k, c.fmt(x, ".3e"), c.fmt(m, ".3e"), c.fmt(q, ".3f")] for s, r, n, k, x, m, q in table])
    print("xi/Mitsuba < 1: xi's image is closer to the reference at equal spp (its environment sampling does better).")
    c.write_csv(out_dir / "peers-env.csv", ["scene", "resolution", "spp", "seeds", "xi_relmse_mean",
                                            "mitsuba_relmse_mean", "relmse_ratio_xi_mitsuba"], table)


if __name__ == "__main__":
    main()
