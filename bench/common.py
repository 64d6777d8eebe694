"""Shared helpers for the bench scripts: find the repo and `xi`, run renders, cache references,
read EXR header attributes, fit log-log slopes and print plain-text tables.

Standard library only; the scripts import numpy/matplotlib themselves where they plot.
"""
import argparse
import csv
import math
import os
import re
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
REFS = ROOT / "bench" / "refs"
OUT = ROOT / "bench" / "out"

# References: the unbiased random sampler with MIS, and a seed no bench run uses (they use 1, 2, 3...).
REF_SEED = 7654321
REF_SAMPLER, REF_STRATEGY = "random", "mis"

# Short names for the bench's own scenes (--scenes material): textured floor, GGX metals, rough dielectric,
# the sky as environment (bench/make_material_scene.py writes it); a product shot of a glTF asset, textured
# and normal-mapped, under the sky, and the same camera turned to the sky alone, every camera ray escaping
# (bench/make_product_scene.py); a textured glTF still life
# (bench/make_asset_scene.py).
BENCH_SCENES = {"engine": "bench/scenes/engine.json", "material": "bench/scenes/material.json",
                "product": "bench/scenes/product.json", "product-sky": "bench/scenes/product-sky.json",
                "textured": "bench/scenes/textured.json",
                "env-sky": "bench/scenes/env-sky.json", "env-sun": "bench/scenes/env-sun.json"}
# --isa (peers.py, widths.py): what each renderer is given to compile for that instruction set instead of this
# CPU's: PoCL's kernel library (POCL_KERNELLIB_NAME), xi's defaults on such a CPU, Dr.Jit's LLVM target.
ISAS = {"avx2": dict(pocl_kernellib="avx2", xi_args=["--lanes", "16", "--packet-width", "8"],
                     llvm_target="haswell:+avx,+avx2,+fma,+f16c,+bmi,+bmi2,+popcnt,+sse4.2,-avx512f:8")}

SUMMARY = re.compile(r"^(\d+)x(\d+), (\d+) spp, ([\d.]+) s, ([\d.]+) Msamples/s, ([\d.]+) Mrays/s$", re.M)


def parser(description):
    """An ArgumentParser with the options every script shares."""
    p = argparse.ArgumentParser(description=description, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--xi", default=str(ROOT / "build" / "xi"), help="the xi program")
    p.add_argument("--out", default=str(OUT), help="folder for tables and plots")
    return p


def find_xi(path):
    xi = Path(path).resolve()
    if not (xi.is_file() and os.access(xi, os.X_OK)):
        sys.exit(f"bench: no xi program at {xi}; build it (cmake -S {ROOT} -B build -DCMAKE_BUILD_TYPE=Release && "
                 f"cmake --build build --target xi) or pass --xi PATH")
    return xi


def scene_path(scene):
    """'cornell-box' -> ROOT/scenes/cornell-box.json, 'engine' -> ROOT/bench/scenes/engine.json (BENCH_SCENES); a
    path is taken relative to the cwd, then to the repo."""
    if scene in BENCH_SCENES:
        return ROOT / BENCH_SCENES[scene]
    if "/" not in scene and not scene.endswith(".json"):
        return ROOT / "scenes" / f"{scene}.json"
    for p in (Path(scene), ROOT / scene):
        if p.is_file():
            return p.resolve()
    sys.exit(f"bench: no scene {scene}")


def parse_resolution(text):
    w, h = text.lower().split("x")
    return int(w), int(h)


def int_list(text):
    return [int(v) for v in text.split(",") if v]


def str_list(text):
    return [v for v in text.split(",") if v]


def run(cmd):
    """Runs a command; on failure prints it with its output and exits."""
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"bench: command failed ({proc.returncode}): {' '.join(map(str, cmd))}\n{proc.stdout}{proc.stderr}")
    if proc.stderr.strip():
        print(proc.stderr.strip(), file=sys.stderr)
    return proc.stdout


_warm = set()


def render(xi, scene, out, spp, seed=1, resolution=None, sampler=None, strategy=None, all_features=False,
           reference=None, convergence=None, warm_up=True, device=None, max_depth=None, args=()):
    """Renders SCENE to OUT (an .exr; xi writes a .png beside it), ARGS added to xi's command line. Returns a
    dict: seconds (render time, from the EXR's renderSeconds), msamples and mrays (per second), features, and
    with a reference rmse and relmse.

    Each (scene, resolution, sampler, strategy, kernel set) is first rendered once at 1 spp, untimed, unless
    warm_up is False, so that no timed render includes a kernel build (or, where PoCL's work-group
    specialisation is on, the work-group functions it compiles per launch size inside the first pass)."""
    key = (str(xi), str(scene), resolution, sampler, strategy, all_features, device, max_depth, tuple(args))
    if warm_up and key not in _warm:
        _warm.add(key)
        render(xi, scene, Path(out).with_name(Path(out).stem + "-warm-up.exr"), 1, seed, resolution, sampler,
               strategy, all_features, warm_up=False, device=device, max_depth=max_depth, args=args)
    cmd = [xi, "render", scene_path(str(scene)), "-o", out, "--spp", spp, "--seed", seed]
    for flag, value in (("--resolution", resolution), ("--sampler", sampler), ("--strategy", strategy),
                        ("--reference", reference), ("--convergence", convergence), ("--device", device),
                        ("--max-depth", max_depth)):
        if value is not None:
            cmd += [flag, value]
    if all_features:
        cmd.append("--all-features")
    stdout = run(cmd + list(args))
    m = SUMMARY.search(stdout)
    if not m:
        sys.exit(f"bench: no summary line in the output of {' '.join(map(str, cmd))}:\n{stdout}")
    attrs = exr_attributes(out)
    w, h, seconds = int(m[1]), int(m[2]), attrs["renderSeconds"]  # the EXR's seconds are not rounded to 0.01
    features = re.search(r"features: (.*)$", stdout, re.M)
    r = dict(seconds=seconds, msamples=w * h * spp / seconds * 1e-6, mrays=float(m[6]),
             features=features[1] if features else "", stdout=stdout)
    if reference is not None:
        r.update(rmse=attrs["error.rmse"], relmse=attrs["error.relmse"])
    return r


def same_work(xi, scene, image, other, spp, seed, resolution):
    """Whether two renders of one seed (IMAGE, OTHER) did the same work: the relMSE of OTHER against IMAGE, and
    that of a render of the next seed against IMAGE (the noise between seeds), with a note when the first is not
    far below the second. Returns (same, noise, warning)."""
    next_seed = Path(image).with_name(Path(image).stem + "-next-seed.exr")
    render(xi, scene, next_seed, spp, seed=seed + 1, resolution=resolution)
    same, noise = diff(xi, other, image, "relmse"), diff(xi, next_seed, image, "relmse")
    warning = "" if same < 0.01 * noise else "\n  <-- the images differ: not the same work, so the ratio is not like for like"
    return same, noise, warning


def diff(xi, image, ref, metric="rmse", crop=None):
    """`xi diff`: one metric of IMAGE against REF, over the crop (x0, y0, x1, y1) if given."""
    cmd = [xi, "diff", image, ref, "--metric", metric]
    if crop:
        cmd += ["--crop", ",".join(map(str, crop))]
    return float(run(cmd))


def devices(xi):
    """Names of the OpenCL devices `xi devices` lists, in its order."""
    lines = run([xi, "devices"]).splitlines()[1:]
    return [re.split(r"\s{2,}", line[4:].strip())[0] for line in lines if line.strip()]


def machine(xi):
    names = devices(xi)
    return f"{len(os.sched_getaffinity(0))} cores, {names[0] if names else 'no device'}"


def reference(xi, scene, resolution, spp, log=print, max_depth=None):
    """A high-spp reference of SCENE at RESOLUTION ('WxH'), rendered once with the random sampler, MIS and
    REF_SEED, and cached as bench/refs/<scene>-<W>x<H>-<spp>spp.exr (-d<K> before .exr for a max depth other
    than the scene's), with its PNG preview beside it. Returns its path."""
    path = scene_path(str(scene))
    w, h = parse_resolution(resolution)
    ref = REFS / f"{path.stem}-{w}x{h}-{spp}spp{'' if max_depth is None else f'-d{max_depth}'}.exr"
    if ref.exists():
        a = exr_attributes(ref)
        x0, y0, x1, y1 = a["dataWindow"]
        if a.get("spp") != spp or (x1 - x0 + 1, y1 - y0 + 1) != (w, h):
            sys.exit(f"bench: {ref} holds {a.get('spp')} spp at {x1 - x0 + 1}x{y1 - y0 + 1}, not its name; delete it")
        log(f"reference: {shown(ref)} (cached, {spp} spp, seed {a.get('seed')})")
        if not ref.with_suffix(".png").exists():  # previews are not committed: made again after a fresh clone
            run([xi, "tonemap", ref, ref.with_suffix(".png")])
        return ref
    REFS.mkdir(parents=True, exist_ok=True)
    log(f"reference: rendering {shown(ref)} ({spp} spp, {REF_SAMPLER} sampler, {REF_STRATEGY}, "
        f"seed {REF_SEED}); this is done once")
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="xi-bench-", dir=REFS) as tmp:  # same file system: rename is atomic
        out = Path(tmp) / ref.name
        render(xi, path, out, spp, seed=REF_SEED, resolution=resolution, sampler=REF_SAMPLER, strategy=REF_STRATEGY,
               max_depth=max_depth)
        os.replace(out.with_suffix(".png"), ref.with_suffix(".png"))
        os.replace(out, ref)
    log(f"reference: done in {time.monotonic() - t0:.0f} s")
    return ref


def shown(path):
    """PATH relative to the repository where it lies inside it (a --refs or --out folder may not)."""
    path = Path(path).resolve()
    return path.relative_to(ROOT) if path.is_relative_to(ROOT) else path


def exr_attributes(path):
    """The header attributes of an OpenEXR file (single part): int, float, double, string and box2i values;
    other types are skipped."""
    data = Path(path).read_bytes()
    if data[:4] != b"\x76\x2f\x31\x01":
        raise ValueError(f"{path} is not an OpenEXR file")
    attrs, pos = {}, 8
    while data[pos] != 0:
        name_end = data.index(b"\0", pos)
        type_end = data.index(b"\0", name_end + 1)
        name, kind = data[pos:name_end].decode(), data[name_end + 1:type_end].decode()
        (size,) = struct.unpack_from("<i", data, type_end + 1)
        value = data[type_end + 5:type_end + 5 + size]
        pos = type_end + 5 + size
        formats = {"int": "<i", "float": "<f", "double": "<d", "box2i": "<4i"}
        if kind in formats:
            v = struct.unpack(formats[kind], value)
            attrs[name] = v[0] if len(v) == 1 else v
        elif kind == "string":
            attrs[name] = value.decode()
    return attrs


def median(values):
    return statistics.median(values)


def loglog_slope(xs, ys):
    """Least-squares slope of log(y) against log(x) over the points where both are positive (nan if < 2)."""
    pts = [(math.log(x), math.log(y)) for x, y in zip(xs, ys) if x > 0 and y > 0]
    if len(pts) < 2:
        return math.nan
    mx = sum(p[0] for p in pts) / len(pts)
    my = sum(p[1] for p in pts) / len(pts)
    sxx = sum((x - mx) ** 2 for x, _ in pts)
    return sum((x - mx) * (y - my) for x, y in pts) / sxx if sxx > 0 else math.nan


def loglog_fit(xs, ys):
    """(intercept, slope) of the least-squares line log(y) = a + b log(x)."""
    b = loglog_slope(xs, ys)
    pts = [(math.log(x), math.log(y)) for x, y in zip(xs, ys) if x > 0 and y > 0]
    a = sum(y - b * x for x, y in pts) / len(pts) if pts else math.nan
    return a, b


def fmt(value, spec):
    """Formats a number, leaving strings as they are and writing nan as '-'."""
    if isinstance(value, str):
        return value
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def print_table(headers, rows, file=None):
    """A plain-text table: columns as wide as their widest cell, text left-aligned, numbers right-aligned."""
    cells = [[str(c) for c in headers]] + [[str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    numeric = [all(re.fullmatch(r"[-+]?[\d.e+-]+[*!<]*|-|—", r[i]) for r in cells[1:]) for i in range(len(headers))]
    for k, row in enumerate(cells):
        line = "  ".join(c.rjust(w) if num else c.ljust(w) for c, w, num in zip(row, widths, numeric))
        print(line.rstrip(), file=file or sys.stdout)
        if k == 0:
            print("  ".join("-" * w for w in widths), file=file or sys.stdout)


def write_csv(path, headers, rows):
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(headers)
        w.writerows(rows)


def read_convergence(path):
    """The rows of an `xi render --convergence` CSV as dicts of numbers."""
    with open(path) as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def pyplot():
    """matplotlib.pyplot with the Agg backend, or an exit telling how to get it."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        return plt
    except ImportError:
        sys.exit("bench: matplotlib is missing: scripts/install-deps.sh --bench installs Debian's python3-matplotlib "
                 "(for /usr/bin/python3)")
