#!/usr/bin/python3
"""Time to the first image of a new scene with empty caches: xi against Mitsuba 3's first render.

For each scene, each of --runs times (medians reported), with fresh temporary XI_CACHE_DIR and POCL_CACHE_DIR
where it says empty, all `xi render SCENE --spp N --resolution WxH`:
  cold      empty caches, no prebuild: the scene's own kernels compile before the first pass. Records the
            first-pass time xi prints ("first pass done ... after start"), its kernel line and the wall time.
  prebuilt  empty caches, then `xi prebuild` (timed: a one-off per device), then the render: the generic
            kernels shade while the scene's own build in the background (goal: first pass < 2 s on 2 cores).
            Its wall time includes waiting at exit for that background build (it fills the cache).
  cached    the same render again in that cache: the kernel line's load time (goal <= 0.05 s), first pass.
  Mitsuba   (llvm_ad_rgb by default) the scene converted once, untimed (`xi export`, then
            bench/mitsuba_scene.py into a scene dict saved as JSON); then per run a fresh bench/.venv python
            process that reads it, calls mi.load_dict and renders once at the same resolution and spp, with
            Dr.Jit's kernel cache empty (DRJIT_CACHE_DIR at a fresh temporary folder): its wall time (Python's
            start and imports included) and the time inside it from before mi.load_dict to the pixels.
            xi's JSON scenes only: an asset file (glTF) or a scene the converter rejects gets n/a.
xi and Mitsuba runs alternate (which goes first flips each run). The table's ratio is xi's prebuilt first
pass over Mitsuba's in-process time (< 1: xi's first image comes sooner).

    python3 bench/cold_start.py                      # the default scenes, 3 runs (about 2 min per scene-run)
    python3 bench/cold_start.py --runs 1 --scenes scenes/cornell-box.json scenes/mirror.json
    python3 bench/cold_start.py --no-mitsuba --csv /tmp/cold.csv

Needs xi built (cmake --build build --target xi) and, for Mitsuba, bench/.venv (bash bench/setup-mitsuba.sh).
Times are of a whole machine: other load on it (builds) shows up in them."""
import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402
import mitsuba_scene as ms  # noqa: E402
import peers  # noqa: E402  (libllvm(), VENV)

DEFAULT_SCENES = ["scenes/cornell-box.json", "scenes/mirror.json", "scenes/caustics.json",
                  "scenes/depth-of-field.json", "scenes/soft-shadows.json", "bench/scenes/engine.json",
                  "/usr/share/assimp/models/glTF2/BoxTextured-glTF/BoxTextured.gltf"]
PREBUILD_GOAL_S, CACHED_LOAD_GOAL_S = 2.0, 0.05

KERNELS = re.compile(r"^kernels: (loaded from cache|compiled) in ([\d.]+) s(.*)$", re.M)
FIRST_PASS = re.compile(r"^first pass done ([\d.]+) s after start(.*)$", re.M)
PREBUILT = re.compile(r"^kernels ready in ([\d.]+) s, cached in (.*)$", re.M)


# ---------------------------------------------------------------------------------------------------------
# Mitsuba side: one fresh process under bench/.venv/bin/python per measurement (this file with --mitsuba-once).

MATRIX = "__matrix__"  # how a transform (4x4; a texture's 3x3) goes into the converted scene's JSON


def transform(mi, rows):
    """A transform decoded from the converted scene's JSON: 4x4 (shapes, emitters) or 3x3 (to_uv)."""
    return mi.ScalarTransform4f(mi.ScalarMatrix4f(rows)) if len(rows) == 4 else mi.ScalarTransform3f(mi.ScalarMatrix3f(rows))


def mitsuba_convert(a):
    """Converts one scene (bench/mitsuba_scene.py, from `xi export` in --export) into --export/mitsuba.json,
    its transforms as matrices; prints one JSON line: the triangles, or why the converter cannot."""
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # whatever Mitsuba prints goes to stderr, not into the reply
    import mitsuba as mi
    import numpy as np
    mi.set_variant(a.mitsuba_variant)
    w, h = c.parse_resolution(a.resolution)
    try:
        d, triangles = ms.convert(a.scene, a.export, w, h, a.max_depth, "independent")
    except ms.Unsupported as e:
        reply.write(json.dumps(dict(unsupported=str(e))) + "\n")
        return
    text = json.dumps(d, default=lambda o: {MATRIX: np.array(o.matrix).tolist()})
    (Path(a.export) / "mitsuba.json").write_text(text)
    reply.write(json.dumps(dict(triangles=triangles)) + "\n")


def mitsuba_once(a):
    """Loads the converted scene in --export and renders it once; prints one JSON line: seconds from
    before mi.load_dict to after the render (pixels read back: Dr.Jit is lazy), and those of the imports."""
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    t0 = time.perf_counter()
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    mi.set_variant(a.mitsuba_variant)
    mi.set_log_level(mi.LogLevel.Warn)
    t1 = time.perf_counter()
    d = json.loads((Path(a.export) / "mitsuba.json").read_text(),
                   object_hook=lambda o: transform(mi, o[MATRIX]) if MATRIX in o else o)
    t2 = time.perf_counter()
    scene = mi.load_dict(d)
    img = mi.render(scene, spp=a.spp, seed=1)
    pixels = np.array(img)  # forces the evaluation
    t3 = time.perf_counter()
    reply.write(json.dumps(dict(seconds=t3 - t2, import_s=t1 - t0, mean=float(pixels.mean()),
                                version=mi.__version__, threads=dr.thread_count())) + "\n")


# ---------------------------------------------------------------------------------------------------------
# Driver side: Debian's /usr/bin/python3, standard library only.

def run_timed(cmd, env):
    """Runs a command; returns (stdout, wall seconds). On failure prints it with its output and exits."""
    t0 = time.monotonic()
    proc = subprocess.run([str(x) for x in cmd], capture_output=True, text=True, env=env)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        sys.exit(f"bench: command failed ({proc.returncode}): {' '.join(map(str, cmd))}\n{proc.stdout}{proc.stderr}")
    return proc.stdout, wall


def need(pattern, text, what, cmd):
    m = pattern.search(text)
    if not m:
        sys.exit(f"bench: no {what} line in the output of {' '.join(map(str, cmd))}:\n{text}")
    return m


def not_empty(folder, what):
    """Fails if FOLDER holds no file: the cache variable pointing there was not honoured."""
    if not any(p.is_file() for p in Path(folder).rglob("*")):
        sys.exit(f"bench: {what} wrote nothing into {folder}: the cache variable was not honoured, so the "
                 f"caches were not the empty ones")


def caches(tmp, tag):
    """Fresh, empty XI_CACHE_DIR and POCL_CACHE_DIR under TMP; returns the environment and both paths."""
    xi_cache, pocl_cache = Path(tempfile.mkdtemp(prefix=f"{tag}-xi-", dir=tmp)), \
        Path(tempfile.mkdtemp(prefix=f"{tag}-pocl-", dir=tmp))
    env = dict(os.environ, XI_CACHE_DIR=str(xi_cache), POCL_CACHE_DIR=str(pocl_cache))
    return env, xi_cache, pocl_cache


def xi_render(a, xi, scene, env, out):
    """One `xi render` (with its summary): its kernel line, first-pass line and wall time."""
    cmd = [xi, "render", scene, "--spp", a.spp, "--resolution", a.resolution, "-o", out]
    stdout, wall = run_timed(cmd, env)
    k, f = need(KERNELS, stdout, "'kernels:'", cmd), need(FIRST_PASS, stdout, "'first pass done'", cmd)
    return dict(kernel_s=float(k[2]), kernel_line=k[0], cached=k[1] == "loaded from cache",
                first_pass_s=float(f[1]), first_pass_line=f[0], wall_s=wall)


def measure_xi(a, xi, scene, tmp, log):
    """The cold, prebuilt and cached renders of one run, each cache its own: a dict of their results."""
    name = scene.stem
    env, xi_cache, pocl_cache = caches(tmp, f"{name}-cold")
    cold = xi_render(a, xi, scene, env, Path(tmp) / f"{name}-cold.exr")
    not_empty(pocl_cache, "PoCL")
    log(f"  xi cold:     {cold['kernel_line']}; first pass {cold['first_pass_s']:.2f} s; wall {cold['wall_s']:.2f} s")

    env, xi_cache, pocl_cache = caches(tmp, f"{name}-prebuilt")
    cmd = [xi, "prebuild"]
    stdout, prebuild_wall = run_timed(cmd, env)
    prebuild_s = float(need(PREBUILT, stdout, "'kernels ready in'", cmd)[1])
    not_empty(xi_cache, "xi prebuild")
    pre = xi_render(a, xi, scene, env, Path(tmp) / f"{name}-prebuilt.exr")
    log(f"  xi prebuild: {prebuild_s:.2f} s (wall {prebuild_wall:.2f} s)")
    log(f"  xi prebuilt: {pre['kernel_line']}; {pre['first_pass_line']}; wall {pre['wall_s']:.2f} s")
    cached = xi_render(a, xi, scene, env, Path(tmp) / f"{name}-cached.exr")
    log(f"  xi cached:   {cached['kernel_line']}; first pass {cached['first_pass_s']:.2f} s; "
        f"wall {cached['wall_s']:.2f} s")
    for what, r in (("prebuilt", pre), ("cached", cached)):
        if not r["cached"]:
            log(f"  WARNING: the {what} render compiled its kernels: the cache did not serve it")
    return dict(cold=cold, prebuilt=pre, cached=cached, prebuild_s=prebuild_s, prebuild_wall_s=prebuild_wall)


class Mitsuba:
    """Runs mitsuba_once in fresh processes under the venv's python."""

    def __init__(self, a, xi, tmp):
        self.a, self.xi, self.tmp = a, xi, tmp
        self.python = Path(a.venv) / "bin" / "python"
        if not self.python.exists():
            sys.exit(f"bench: no Mitsuba venv at {a.venv}: run bash bench/setup-mitsuba.sh, or pass --no-mitsuba")
        self.env = dict(os.environ)
        if a.mitsuba_variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in self.env:
            self.env["DRJIT_LIBLLVM_PATH"] = peers.libllvm()
        self.exports, self.info = {}, None

    def export(self, scene):
        """`xi export` of SCENE, once, untimed; None (after saying why) if the converter cannot take it."""
        if scene not in self.exports:
            why = None
            if scene.suffix != ".json":
                why = "not an xi JSON scene (the converter reads xi's JSON for the camera and materials)"
            else:
                try:
                    export = ms.export(self.xi, scene, Path(self.tmp) / f"export-{scene.stem}")
                    r = self.ask("--mitsuba-convert", scene, export)
                    why = r.get("unsupported")
                    self.exports[scene] = export
                except ms.Unsupported as e:
                    why = str(e)
            if why:
                print(f"mitsuba: {scene.stem}: n/a: {why}", file=sys.stderr)
                self.exports[scene] = None
        return self.exports[scene]

    def ask(self, what, scene, export, env=None):
        """This file under the venv's python with WHAT (--mitsuba-convert or --mitsuba-once): its JSON reply
        and its wall time."""
        cmd = [self.python, __file__, what, "--scene", scene, "--export", export, "--resolution",
               self.a.resolution, "--spp", self.a.spp, "--max-depth", self.a.max_depth or peers.scene_depth(scene),
               "--mitsuba-variant", self.a.mitsuba_variant]
        stdout, wall = run_timed(cmd, env or self.env)
        lines = stdout.strip().splitlines()
        if not lines:
            sys.exit(f"bench: no reply from {' '.join(map(str, cmd))}")
        return dict(json.loads(lines[-1]), wall_s=wall)

    def render(self, scene):
        """One fresh process with an empty Dr.Jit cache: dict(wall_s, seconds, ...), or None if unsupported."""
        export = self.export(scene)
        if export is None:
            return None
        jit_cache = tempfile.mkdtemp(prefix=f"{scene.stem}-drjit-", dir=self.tmp)
        r = self.ask("--mitsuba-once", scene, export, dict(self.env, DRJIT_CACHE_DIR=jit_cache))
        not_empty(jit_cache, "Dr.Jit")
        self.info = self.info or r
        return r


def med(values):
    return c.median(values) if values else math.nan


def measure(a, xi, mitsuba, scene, tmp):
    """--runs interleaved runs of xi and Mitsuba on one scene: one result row (medians)."""
    def log(m):
        print(m, file=sys.stderr)
    xi_runs, mi_runs, mi_na = [], [], mitsuba is None
    for i in range(a.runs):
        for who in ("xi", "mitsuba")[::1 if i % 2 == 0 else -1]:
            if who == "xi":
                log(f"{scene.stem}, run {i + 1}/{a.runs}: xi")
                xi_runs.append(measure_xi(a, xi, scene, tmp, log))
            elif not mi_na:
                r = mitsuba.render(scene)
                if r is None:
                    mi_na = True
                    continue
                log(f"{scene.stem}, run {i + 1}/{a.runs}: Mitsuba: wall {r['wall_s']:.2f} s, load + render "
                    f"{r['seconds']:.2f} s (imports {r['import_s']:.2f} s)")
                mi_runs.append(r)
    row = dict(scene=scene.stem, resolution=a.resolution, spp=a.spp, runs=a.runs)
    for kind in ("cold", "prebuilt", "cached"):
        for key in ("first_pass_s", "wall_s", "kernel_s"):
            row[f"xi_{kind}_{key}"] = med([r[kind][key] for r in xi_runs])
    row["xi_cold_kernel_line"] = xi_runs[-1]["cold"]["kernel_line"]
    row["xi_prebuilt_first_pass_line"] = xi_runs[-1]["prebuilt"]["first_pass_line"]
    row["xi_prebuild_s"] = med([r["prebuild_s"] for r in xi_runs])
    row["xi_prebuild_wall_s"] = med([r["prebuild_wall_s"] for r in xi_runs])
    for key in ("wall_s", "seconds", "import_s"):
        row[f"mitsuba_{key}"] = "n/a" if mi_na else med([r[key] for r in mi_runs])
    row["ratio"] = "n/a" if mi_na else row["xi_prebuilt_first_pass_s"] / row["mitsuba_seconds"]
    return row


class HelpFormat(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """The docstring as written, and the defaults."""


def main():
    p = c.parser(__doc__)
    p.formatter_class = HelpFormat
    p.add_argument("--scenes", nargs="+", default=DEFAULT_SCENES,
                   help="xi scene files (or names in scenes/) and asset files, space- or comma-separated")
    p.add_argument("--resolution", default="512x512")
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--max-depth", type=int, help="Mitsuba: xi's bounces (it gets one more); default: the scene's")
    p.add_argument("--runs", type=int, default=3, help="runs of each measurement, interleaved; medians")
    p.add_argument("--csv", help="the table as CSV (default: cold_start.csv in --out)")
    p.add_argument("--no-mitsuba", action="store_true", help="xi only")
    p.add_argument("--mitsuba-variant", default="llvm_ad_rgb", help="cuda_ad_rgb on an NVIDIA GPU")
    p.add_argument("--venv", default=str(peers.VENV), help="the venv with Mitsuba (bench/setup-mitsuba.sh)")
    p.add_argument("--mitsuba-convert", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--mitsuba-once", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--scene", help=argparse.SUPPRESS)
    p.add_argument("--export", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.mitsuba_convert:
        return mitsuba_convert(a)
    if a.mitsuba_once:
        return mitsuba_once(a)
    xi = c.find_xi(a.xi)
    scenes = [Path(c.scene_path(s)) for arg in a.scenes for s in c.str_list(arg)]
    csv_path = Path(a.csv) if a.csv else Path(a.out) / "cold_start.csv"
    print(f"xi: {xi} ({c.machine(xi)}); {a.resolution}, {a.spp} spp, {a.runs} run(s)", file=sys.stderr)

    with tempfile.TemporaryDirectory(prefix="xi-cold-start-") as tmp:
        mitsuba = None if a.no_mitsuba else Mitsuba(a, xi, tmp)
        rows = [measure(a, xi, mitsuba, scene, tmp) for scene in scenes]
    info = mitsuba.info if mitsuba else None

    def goal(value, limit):  # '!': the goal missed
        return c.fmt(value, ".3f") + ("!" if value > limit else "")
    headers = ["scene", "xi cold 1st pass", "xi cold wall", "xi prebuilt 1st pass", "xi prebuilt wall",
               "xi cached kernels", "xi cached 1st pass", "Mitsuba wall", "Mitsuba in-process",
               "prebuilt / Mitsuba"]
    table = [[r["scene"], c.fmt(r["xi_cold_first_pass_s"], ".2f"), c.fmt(r["xi_cold_wall_s"], ".2f"),
              goal(r["xi_prebuilt_first_pass_s"], PREBUILD_GOAL_S), c.fmt(r["xi_prebuilt_wall_s"], ".2f"),
              goal(r["xi_cached_kernel_s"], CACHED_LOAD_GOAL_S), c.fmt(r["xi_cached_first_pass_s"], ".2f"),
              c.fmt(r["mitsuba_wall_s"], ".2f"), c.fmt(r["mitsuba_seconds"], ".2f"), c.fmt(r["ratio"], ".3f")]
             for r in rows]
    mi_name = f"Mitsuba {info['version']} {a.mitsuba_variant}, {info['threads']} threads" if info else \
        "Mitsuba: not run" if a.no_mitsuba else f"Mitsuba {a.mitsuba_variant}"
    print(f"\nTime to the first image with empty caches, seconds, medians of {a.runs} interleaved run(s); "
          f"{a.resolution}, {a.spp} spp; {c.machine(xi)}; {mi_name}")
    c.print_table(headers, table)
    prebuilds = [r["xi_prebuild_s"] for r in rows]
    print(f"xi prebuild (a one-off per device): {c.fmt(med(prebuilds), '.2f')} s (median over the scenes' fresh "
          f"caches; per scene {', '.join(c.fmt(v, '.2f') for v in prebuilds)}), wall "
          f"{c.fmt(med([r['xi_prebuild_wall_s'] for r in rows]), '.2f')} s")
    print(f"1st pass: xi's 'first pass done ... after start', from the command's start (scene load, device and "
          f"kernels, BVH included).\n"
          f"cold: empty caches, no prebuild. prebuilt: empty caches, then `xi prebuild`; its wall includes the "
          f"wait at exit for the scene's own build. cached: the same render again.\n"
          f"'!': over the goal ({PREBUILD_GOAL_S:g} s prebuilt first pass, {CACHED_LOAD_GOAL_S:g} s cached kernel "
          f"load). Mitsuba wall: a fresh Python process, empty Dr.Jit cache; in-process: from mi.load_dict to the "
          f"pixels (its imports excluded).\n"
          f"prebuilt / Mitsuba: xi's prebuilt first pass over Mitsuba's in-process time (< 1: xi's image is sooner).")
    keys = list(rows[0])
    c.write_csv(csv_path, keys + ["mitsuba_variant"],
                [[round(r[k], 4) if isinstance(r[k], float) else r[k] for k in keys] + [a.mitsuba_variant]
                 for r in rows])
    print(f"wrote {csv_path}")


if __name__ == "__main__":
    main()
