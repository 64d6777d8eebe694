#!/usr/bin/python3
"""Time to error: for each scene, the error each renderer and mode reaches against render time and against
samples per pixel, and the time each takes to reach given relMSE targets.

Renderers and modes (curves):
  xi         uniform (--spp N), adaptive (--noise-threshold T, capped at the largest --spps), denoised
             (--denoise: OIDN on the mean) and adaptive+denoised. Modes whose flags this xi does not take are
             reported as unavailable (found from `xi render --help` and one tiny render each).
  Mitsuba 3  the independent and ldsampler samplers (path integrator, llvm_ad_rgb), through
             bench/mitsuba_scene.py; ldsampler only at the spp it takes as they are (4, 16, 64, ...).
  Cycles     uniform, adaptive (Cycles' adaptive sampling at each noise threshold), oidn (OpenImageDenoise,
             adaptive off) and adaptive+oidn, CPU device, through bench/cycles_scene.py (Blender's glTF
             importer for asset shapes).

Each renderer's error is measured against a high-spp reference of its own (bench/refs/, made once), so that
differences between the renderers' models do not count: xi's is common.reference's (random sampler, MIS);
Mitsuba's (-mitsuba.exr, independent sampler) and Cycles' (-cycles.exr, uniform) are written by this script
as K renders of ref_spp / K with seeds REF_SEED + k, averaged, the reference's own relMSE estimated from their
spread (the 'floor', in its EXR's relmseFloor attribute). Metrics: relMSE as `xi diff` computes it, mean over
pixels and channels of (x - r)^2 / (r^2 + 0.01), and HDR-FLIP (NVIDIA's flip-evaluator, where installed in
bench/.venv).

Time: what each renderer measures itself: xi's renderSeconds (+ denoiseSeconds) from its EXR, Mitsuba's
seconds around mi.render (and reading the pixels), Cycles' seconds around bpy.ops.render.render (its scene
kept between renders: persistent data). The plots and the table use these; the CSV also has each render's
wall time (xi: the whole process; Mitsuba and Cycles: the request to their worker, image writing included).
Each point is the median of --runs renders of seeds 1, 2, ...; runs are interleaved across modes, and every
timed configuration is first rendered once untimed (kernel builds, Dr.Jit's tracing, Cycles' BVH).

Mitsuba runs in bench/.venv (bench/setup-mitsuba.sh), Cycles in bench/.venv-bpy (bench/setup-cycles.sh), each
as a worker process kept for the whole run; this script needs Debian's python3-numpy and python3-matplotlib."""
import json
import math
import os
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

try:
    import numpy as np
    import exr  # noqa: E402  (needs numpy)
except ImportError:
    sys.exit("bench: numpy is missing: scripts/install-deps.sh --bench installs Debian's python3-numpy "
             "(for /usr/bin/python3)")

BENCH = c.ROOT / "bench"
DEFAULT_SCENES = ["cornell-box", "textured", "engine"]
MITSUBA_VENV, CYCLES_VENV = BENCH / ".venv", BENCH / ".venv-bpy"
TARGETS = [1e-2, 3e-3, 1e-3]
# Peer references are K renders of ref_spp / K each: their spread gives the reference's own error, and no
# single Mitsuba render holds more than this many samples at once (Dr.Jit keeps a wavefront of them all).
REF_PARTS, MITSUBA_MAX_SAMPLES = 4, 1 << 24

# (renderer, mode) -> how the curve is swept: over spp ('spp') or over noise thresholds ('threshold').
MODES = {("xi", "uniform"): "spp", ("xi", "adaptive"): "threshold", ("xi", "denoised"): "spp",
         ("xi", "adaptive+denoised"): "threshold",
         ("mitsuba", "independent"): "spp", ("mitsuba", "ldsampler"): "spp",
         ("cycles", "uniform"): "spp", ("cycles", "adaptive"): "threshold", ("cycles", "oidn"): "spp",
         ("cycles", "adaptive+oidn"): "threshold"}
# xi's flags per mode (the threshold goes after --noise-threshold).
XI_FLAGS = {"uniform": [], "adaptive": ["--noise-threshold"], "denoised": ["--denoise"],
            "adaptive+denoised": ["--noise-threshold", "--denoise"]}

FLIP_WORKER = r"""
import json, sys
import numpy as np
from importlib.metadata import version
import flip_evaluator as flip
print(json.dumps({"version": version("flip-evaluator")}), flush=True)
for line in sys.stdin:
    test, ref = json.loads(line)
    _, mean, _ = flip.evaluate(np.load(ref), np.load(test), "HDR", applyMagma=False)
    print(json.dumps(float(mean)), flush=True)
"""


def log(message):
    print(message, file=sys.stderr, flush=True)


def relmse(image, ref):
    """`xi diff --metric relmse`: the mean over pixels and channels of (x - r)^2 / (r^2 + 0.01)."""
    return float(((image - ref) ** 2 / (ref ** 2 + 0.01)).mean())


class Worker:
    """A process answering one JSON line per request line, kept for the whole run. A worker that does not
    answer within the timeout is stopped and the bench exits naming the request."""

    def __init__(self, name, cmd, timeout, env=None):
        self.name, self.timeout = name, timeout
        self.proc = subprocess.Popen([str(x) for x in cmd], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, env=env)

    def read(self, what):
        if not select.select([self.proc.stdout], [], [], self.timeout)[0]:
            self.proc.kill()
            sys.exit(f"bench: the {self.name} worker gave no answer to '{what}' in {self.timeout:g} s "
                     f"(--worker-timeout)")
        line = self.proc.stdout.readline()
        if not line:
            sys.exit(f"bench: the {self.name} worker stopped (exit status {self.proc.wait()}; its messages are "
                     f"above)")
        return json.loads(line)

    def ask(self, **req):
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        return self.read(req.get("cmd", "?"))

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


class Flip:
    """HDR-FLIP in bench/.venv (flip-evaluator), or None where it is not installed."""

    @staticmethod
    def start(timeout):
        python = MITSUBA_VENV / "bin" / "python"
        if not python.exists() or subprocess.run([python, "-c", "import flip_evaluator"],
                                                 capture_output=True).returncode != 0:
            return None
        w = Worker("FLIP", [python, "-c", FLIP_WORKER], timeout)
        w.version = w.read("start")["version"]
        return w


def flip_error(flip, image, ref_npy, tmp):
    if flip is None:
        return math.nan
    test = Path(tmp) / "flip-test.npy"
    np.save(test, np.clip(image, 0, None).astype(np.float32))  # HDR-FLIP takes non-negative values
    flip.proc.stdin.write(json.dumps([str(test), str(ref_npy)]) + "\n")
    flip.proc.stdin.flush()
    return flip.read("flip")


# ---------------------------------------------------------------------------------------------------------
# xi

def xi_command(xi, scene, out, spp, seed, resolution, sampler, mode, threshold, min_spp):
    cmd = [xi, "render", scene, "-o", out, "--spp", spp, "--seed", seed, "--resolution", resolution, "--quiet"]
    if sampler:
        cmd += ["--sampler", sampler]
    for flag in XI_FLAGS[mode]:
        cmd += [flag] + ([threshold] if flag == "--noise-threshold" else [])
    if threshold is not None and min_spp is not None:
        cmd += ["--min-spp", min_spp]
    return [str(x) for x in cmd]


def spp_layer(channels):
    """The per-pixel sample counts of an adaptive xi render (layer spp: spp, or spp.R/G/B alike), or None."""
    names = [n for n in channels if n == "spp" or n.startswith("spp.")]
    return np.mean([channels[n] for n in names], axis=0) if names else None


def xi_modes(xi, tmp, min_spp):
    """Which xi modes this binary renders: {mode: None if available, else why not}. A mode's flags must be in
    `xi render --help` and a tiny render with them must succeed and write what the mode promises."""
    text = subprocess.run([str(xi), "render", "--help"], capture_output=True, text=True).stdout
    status = {}
    for mode, flags in XI_FLAGS.items():
        missing = [f for f in flags + (["--min-spp"] if "--noise-threshold" in flags and min_spp is not None
                                       else []) if f not in text]
        if missing:
            status[mode] = f"unavailable: this xi takes no {', '.join(missing)}"
            continue
        out = Path(tmp) / f"probe-{mode.replace('+', '-')}.exr"
        threshold = 0.1 if "--noise-threshold" in flags else None
        probe_spp = max(4, 2 * (min_spp or 0))  # (adaptive: some pixels get to stop)
        r = subprocess.run(xi_command(xi, c.ROOT / "scenes" / "cornell-box.json", out, probe_spp, 1, "16x16", None,
                                      mode, threshold, min_spp), capture_output=True, text=True)
        if r.returncode != 0:
            status[mode] = "unavailable: " + (r.stderr.strip().splitlines() or ["failed"])[-1]
            continue
        channels, attrs = exr.read(out)
        if "--noise-threshold" in flags and spp_layer(channels) is None:
            status[mode] = "unavailable: the adaptive render wrote no spp layer"
        elif "--denoise" in flags and "denoiseSeconds" not in attrs:
            status[mode] = "unavailable: the denoised render has no denoiseSeconds"
        else:
            status[mode] = None
    return status


def xi_render(a, xi, scene, out, spp, seed, mode, threshold):
    """One xi render: (image, seconds, wall seconds, mean spp)."""
    t0 = time.perf_counter()
    c.run(xi_command(xi, scene, out, spp, seed, a.resolution, a.xi_sampler, mode, threshold, a.min_spp))
    wall = time.perf_counter() - t0
    channels, attrs = exr.read(out)
    image = np.stack([channels[ch] for ch in "RGB"], axis=-1)
    seconds = attrs["renderSeconds"] + attrs.get("denoiseSeconds", 0.0)
    counts = spp_layer(channels)
    mean_spp = float(counts.mean()) if counts is not None else float(attrs.get("spp", spp))
    return image, seconds, wall, mean_spp


# ---------------------------------------------------------------------------------------------------------
# Peer references: bench/refs/<scene>-<W>x<H>-<spp>spp-<renderer>.exr

def peer_reference(xi, kind, scene, resolution, ref_spp, render_part, describe):
    """The cached reference of renderer KIND, or one made now from REF_PARTS renders of ref_spp / REF_PARTS
    each (RENDER_PART(spp, seed) -> image), averaged; their spread estimates the reference's own relMSE.
    Returns (image, floor)."""
    w, h = c.parse_resolution(resolution)
    path = c.REFS / f"{scene.stem}-{w}x{h}-{ref_spp}spp-{kind}.exr"
    if path.exists():
        image, attrs = exr.rgb(path)
        if attrs.get("spp") != ref_spp or image.shape[:2] != (h, w):
            sys.exit(f"bench: {path} holds {attrs.get('spp')} spp at {image.shape[1]}x{image.shape[0]}, not its name; "
                     f"delete it")
        log(f"reference: {c.shown(path)} (cached)")
        return image, attrs.get("relmseFloor", math.nan)
    parts = max(1, min(REF_PARTS, ref_spp))
    log(f"reference: rendering {c.shown(path)} ({describe}, {parts} renders of {ref_spp // parts} spp, "
        f"seeds {c.REF_SEED}...); this is done once")
    t0 = time.monotonic()
    images = np.stack([render_part(ref_spp // parts, c.REF_SEED + k) for k in range(parts)])
    image = images.mean(axis=0)
    floor = float((images.var(axis=0, ddof=1) / parts / (image ** 2 + 0.01)).mean()) if parts > 1 else math.nan
    c.REFS.mkdir(parents=True, exist_ok=True)
    exr.write(path, image, dict(spp=ref_spp // parts * parts, seed=c.REF_SEED, renderer=kind, sampler=describe,
                                relmseFloor=floor))
    subprocess.run([str(xi), "tonemap", str(path), str(path.with_suffix(".png"))], capture_output=True)
    log(f"reference: done in {time.monotonic() - t0:.0f} s")
    return image, floor


def xi_reference(xi, scene, resolution, ref_spp):
    """common.reference's cached xi reference, and its own relMSE from its variance layer."""
    path = c.reference(xi, scene, resolution, ref_spp, log=log)
    channels, _ = exr.read(path)
    image = np.stack([channels[ch] for ch in "RGB"], axis=-1)
    var = np.stack([channels[f"variance.{ch}"] for ch in "RGB"], axis=-1)
    return image, float((var / (image ** 2 + 0.01)).mean())


# ---------------------------------------------------------------------------------------------------------
# Mitsuba and Cycles

MITSUBA_SAMPLERS = [mode for renderer, mode in MODES if renderer == "mitsuba"]


def start_mitsuba(a):
    """One worker per sampler (peers.py's), so that no scene is loaded again between runs and Dr.Jit's
    compiled kernels stay in memory."""
    if not (MITSUBA_VENV / "bin" / "python").exists():
        return None, "unavailable: no bench/.venv (bash bench/setup-mitsuba.sh)"
    env = dict(os.environ)
    if a.mitsuba_variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in env:
        import peers
        env["DRJIT_LIBLLVM_PATH"] = peers.libllvm()
    workers = {}
    for sampler in MITSUBA_SAMPLERS:
        workers[sampler] = Worker(f"Mitsuba ({sampler})", [MITSUBA_VENV / "bin" / "python", BENCH / "peers.py",
                                                           "--worker", "--mitsuba-variant", a.mitsuba_variant],
                                  a.worker_timeout, env)
        workers[sampler].info = workers[sampler].ask(cmd="hello")
    return workers, None


def start_cycles(a):
    if not (CYCLES_VENV / "bin" / "python").exists():
        return None, "unavailable: no bench/.venv-bpy (bash bench/setup-cycles.sh)"
    w = Worker("Cycles", [CYCLES_VENV / "bin" / "python", BENCH / "cycles_scene.py"], a.worker_timeout)
    w.info = w.ask(cmd="hello")
    return w, None


def mitsuba_load(w, scene, export_dir, resolution, depth, sampler):
    width, height = c.parse_resolution(resolution)
    r = w.ask(cmd="load", scene=str(scene), export=str(export_dir), width=width, height=height, max_depth=depth,
              sampler=sampler)
    return r.get("unsupported")


def mitsuba_render(w, spp, seed, tmp):
    """(image, seconds, wall seconds) of one Mitsuba render."""
    out = Path(tmp) / "mitsuba.npy"
    t0 = time.perf_counter()
    r = w.ask(cmd="render", spp=spp, seed=seed, out=str(out))
    return np.load(out).astype(np.float64), r["seconds"], time.perf_counter() - t0


def cycles_render(w, spp, seed, mode, threshold, min_spp, tmp):
    """(image, seconds, wall seconds, mean spp) of one Cycles render in MODE."""
    out = Path(tmp) / "cycles.exr"
    req = dict(cmd="render", spp=spp, seed=seed, out=str(out), denoise=mode in ("oidn", "adaptive+oidn"))
    if threshold is not None:
        req.update(adaptive_threshold=threshold, min_spp=min_spp or 0)
    t0 = time.perf_counter()
    r = w.ask(**req)
    wall = time.perf_counter() - t0
    channels, _ = exr.read(out)
    image = np.stack([channels[f"ViewLayer.Combined.{ch}"] for ch in "RGB"], axis=-1)
    count = channels.get("ViewLayer.Debug Sample Count.X")  # the fraction of the spp each pixel took
    mean_spp = float(count.mean() * spp) if count is not None else float(spp)
    return image, r["seconds"], wall, mean_spp


# ---------------------------------------------------------------------------------------------------------
# Curves, times to targets, table, plots

def sweep(a, mode_kind, renderer, mode):
    """The parameters of a curve: spps, or (threshold, cap) pairs."""
    if mode_kind == "spp":
        spps = sorted(a.spps)
        if (renderer, mode) == ("mitsuba", "ldsampler"):  # it rounds others up to a power of four (4 at least)
            spps = [s for s in spps if s >= 4 and s & (s - 1) == 0 and s.bit_length() % 2 == 1]
        return spps
    return sorted(a.cycles_thresholds if renderer == "cycles" else a.thresholds, reverse=True)  # more work along


def time_to(points, target):
    """(seconds, mark) to reach relMSE <= TARGET along a curve of (seconds, relmse) in sweep order: log-log
    interpolation between the points around the first crossing; '<' if the first point is already below;
    (nan, '') if never reached."""
    prev = None
    for t, e in points:
        if e <= target:
            if prev is None:
                return t, "<"
            (t0, e0), (t1, e1) = prev, (t, e)
            if e0 <= 0 or e1 <= 0 or t0 <= 0 or t1 <= 0 or e1 == e0:
                return t, ""
            f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0))), ""
        prev = (t, e)
    return math.nan, ""


def medians(runs):
    """Per parameter, in sweep order: median seconds, wall, spp, relMSE and FLIP over the runs."""
    out = []
    for param, rs in runs.items():
        out.append(dict(param=param, **{k: c.median([r[k] for r in rs]) if all(not math.isnan(r[k]) for r in rs)
                                        else math.nan for k in ("seconds", "wall", "spp", "relmse", "flip")}))
    return out


def label(renderer, mode):
    return f"{renderer} {mode}"


# Plot styles: a colour family and a line style per renderer, a marker per mode.
FAMILY = {"xi": (["tab:blue", "navy", "deepskyblue", "slateblue"], "-"),
          "mitsuba": (["darkorange", "saddlebrown"], "--"),
          "cycles": (["tab:green", "olive", "limegreen", "darkgreen"], ":")}
MARKERS = "osD^"


def plot(path, title, curves, floors, have_flip):
    plt = c.pyplot()
    panels = 3 if have_flip else 2
    fig, axes = plt.subplots(1, panels, figsize=(6 * panels, 6))
    for (renderer, mode), pts in curves.items():
        if not pts:
            continue
        k = [m for r, m in MODES if r == renderer].index(mode)
        colours, ls = FAMILY[renderer]
        kw = dict(ls=ls, color=colours[k], marker=MARKERS[k], ms=3.5, label=label(renderer, mode))
        axes[0].loglog([p["seconds"] for p in pts], [p["relmse"] for p in pts], **kw)
        axes[1].loglog([p["spp"] for p in pts], [p["relmse"] for p in pts], **kw)
        if have_flip:
            axes[2].loglog([p["seconds"] for p in pts], [p["flip"] for p in pts], **kw)
    for ax in axes[:2]:
        for t in TARGETS:
            ax.axhline(t, color="grey", ls=":", lw=0.8)
        for renderer, floor in floors.items():
            if floor and not math.isnan(floor):
                ax.axhline(floor, color=FAMILY[renderer][0][0], lw=0.7, alpha=0.6)
    axes[0].set(xlabel="render seconds (each renderer's own clock)", ylabel="relMSE")
    axes[1].set(xlabel="samples per pixel (mean)", ylabel="relMSE")
    if have_flip:
        axes[2].set(xlabel="render seconds", ylabel="HDR-FLIP (mean)")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(5, len(labels)), fontsize=8)
    fig.suptitle(title + "\nthin coloured lines: each renderer's reference's own relMSE; grey dotted: the targets",
                 fontsize=9)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def report(scene_name, resolution, curves, status, floors):
    """The table for one scene: rows of (mode, status or numbers)."""
    times = {}
    for key, pts in curves.items():
        times[key] = [time_to([(p["seconds"], p["relmse"]) for p in pts], t) for t in TARGETS]
    best = []
    for k in range(len(TARGETS)):
        xi_times = [times[key][k][0] for key in times if key[0] == "xi" and not math.isnan(times[key][k][0])]
        best.append(min(xi_times) if xi_times else math.nan)
    headers = ["renderer", "mode", "points", "last spp", "last s", "last relMSE", "last FLIP"]
    for t in TARGETS:
        headers += [f"t({t:g})", "/xi best"]
    headers.append("note")
    rows, csv_rows = [], []
    for key in MODES:
        renderer, mode = key
        if key not in status:
            continue
        if status[key]:
            rows.append([renderer, mode] + ["-"] * (len(headers) - 3) + [status[key]])
            csv_rows.append([scene_name, resolution, renderer, mode, status[key]] + [""] * (4 + 3 * len(TARGETS)))
            continue
        pts = curves[key]
        last = pts[-1]
        floor = floors.get(renderer, math.nan)
        low = not math.isnan(floor) and last["relmse"] < 4 * floor
        row = [renderer, mode, len(pts), c.fmt(last["spp"], ".4g"), c.fmt(last["seconds"], ".3g"),
               c.fmt(last["relmse"], ".3e") + "!" * low, c.fmt(last["flip"], ".4f")]
        csv_row = [scene_name, resolution, renderer, mode, "", len(pts), last["spp"], last["seconds"], last["relmse"]]
        for k, (t, mark) in enumerate(times[key]):
            ratio = t / best[k] if not math.isnan(t) and not math.isnan(best[k]) else math.nan
            row += ["—" if math.isnan(t) else c.fmt(t, ".3g") + mark,
                    "—" if math.isnan(ratio) else c.fmt(ratio, ".2f") + mark]
            csv_row += [t, mark, ratio]
        rows.append(row + [""])
        csv_rows.append(csv_row)
    return headers, rows, csv_rows


# ---------------------------------------------------------------------------------------------------------

def measure_scene(a, xi, scene, workers, flip, xi_status, tmp):
    """All curves of one scene: {(renderer, mode): [median point per parameter]}, status, floors, point rows."""
    name = scene.stem
    depth = json.loads(scene.read_text()).get("render", {}).get("max_depth", 8)
    status = {}
    for key in MODES:
        renderer, mode = key
        if renderer not in a.renderers or (a.modes and label(renderer, mode).replace(" ", "-") not in a.modes
                                           and mode not in a.modes):
            continue
        status[key] = xi_status.get(mode) if renderer == "xi" else workers[renderer][1]
    export_dir = Path(tmp) / f"export-{name}"
    peers_needed = any(r != "xi" and not s for (r, _), s in status.items())
    if peers_needed:
        try:
            ms.export(xi, scene, export_dir)
        except ms.Unsupported as e:
            for key in status:
                if key[0] != "xi":
                    status[key] = f"unsupported: {e}"

    refs, floors = {}, {}
    if any(r == "xi" and not s for (r, _), s in status.items()):
        refs["xi"], floors["xi"] = xi_reference(xi, scene, a.resolution, a.ref_spp)
    mitsuba, cycles = workers["mitsuba"][0], workers["cycles"][0]
    if any(r == "mitsuba" and not s for (r, _), s in status.items()):
        why = None
        for sampler in MITSUBA_SAMPLERS:
            why = why or mitsuba_load(mitsuba[sampler], scene, export_dir, a.resolution, depth, sampler)
        if why:
            for key in status:
                if key[0] == "mitsuba":
                    status[key] = f"unsupported: {why}"
        else:
            w, h = c.parse_resolution(a.resolution)
            part_spp = max(1, MITSUBA_MAX_SAMPLES // (w * h))

            def mitsuba_part(spp, seed):  # a reference part, itself in renders of at most part_spp
                chunks = [min(part_spp, spp - k) for k in range(0, spp, part_spp)]
                return sum(mitsuba_render(mitsuba["independent"], n, seed + REF_PARTS * i, tmp)[0] * n
                           for i, n in enumerate(chunks)) / spp
            refs["mitsuba"], floors["mitsuba"] = peer_reference(xi, "mitsuba", scene, a.resolution, a.ref_spp,
                                                                mitsuba_part, "independent sampler")
    if any(r == "cycles" and not s for (r, _), s in status.items()):
        width, height = c.parse_resolution(a.resolution)
        r = cycles.ask(cmd="load", scene=str(scene), export=str(export_dir), width=width, height=height,
                       max_depth=depth)
        if "unsupported" in r:
            for key in status:
                if key[0] == "cycles":
                    status[key] = f"unsupported: {r['unsupported']}"
        else:
            log(f"cycles: {name}: {r['triangles']} triangles, sampling pattern {r['pattern']}")
            cycles.ask(cmd="render", spp=1, seed=0, out=str(Path(tmp) / "cycles-warm-up.exr"))  # BVH, shaders
            refs["cycles"], floors["cycles"] = peer_reference(
                xi, "cycles", scene, a.resolution, a.ref_spp,
                lambda spp, seed: cycles_render(cycles, spp, seed, "uniform", None, None, tmp)[0], "uniform")
    ref_npy = {}
    for renderer, image in refs.items():
        ref_npy[renderer] = Path(tmp) / f"ref-{name}-{renderer}.npy"
        np.save(ref_npy[renderer], image.astype(np.float32))

    runs = {key: {} for key, s in status.items() if not s}
    point_rows = []
    warm = set()
    max_spp = a.adaptive_max_spp or max(a.spps)
    for run in range(a.runs):
        seed = run + 1
        for key in runs:
            renderer, mode = key
            kind = MODES[key]
            for param in sweep(a, kind, renderer, mode):
                spp, threshold = (param, None) if kind == "spp" else (max_spp, param)
                if renderer == "xi":
                    out = Path(tmp) / f"xi-{name}.exr"
                    if (key, name) not in warm:  # the kernels this mode's flags select, built untimed
                        warm.add((key, name))
                        xi_render(a, xi, scene, out, 1, 0, mode, threshold)
                    image, seconds, wall, mean_spp = xi_render(a, xi, scene, out, spp, seed, mode, threshold)
                elif renderer == "mitsuba":
                    if (key, spp) not in warm:  # Dr.Jit traces and compiles per spp: untimed once
                        warm.add((key, spp))
                        mitsuba_render(mitsuba[mode], spp, 0, tmp)
                    image, seconds, wall = mitsuba_render(mitsuba[mode], spp, seed, tmp)
                    mean_spp = float(spp)
                else:
                    if key not in warm:  # the first denoised render loads OIDN
                        warm.add(key)
                        cycles_render(cycles, 1, 0, mode, threshold, a.min_spp, tmp)
                    image, seconds, wall, mean_spp = cycles_render(cycles, spp, seed, mode, threshold, a.min_spp, tmp)
                if not np.isfinite(image).all():
                    sys.exit(f"bench: {label(renderer, mode)} wrote non-finite pixels ({name}, {param})")
                e = relmse(image, refs[renderer])
                f = flip_error(flip, image, ref_npy[renderer], tmp)
                runs[key].setdefault(param, []).append(dict(seconds=seconds, wall=wall, spp=mean_spp, relmse=e, flip=f))
                point_rows.append([name, a.resolution, renderer, mode, kind, param, seed, seconds, wall, mean_spp,
                                   e, f])
                log(f"  {name} {label(renderer, mode):26s} {kind} {param:<6g} seed {seed}: {seconds:8.3f} s  "
                    f"{mean_spp:7.1f} spp  relMSE {e:.3e}" + ("" if math.isnan(f) else f"  FLIP {f:.4f}"))
    curves = {key: medians(r) for key, r in runs.items()}
    return curves, status, floors, point_rows


def main():
    p = c.parser(__doc__)
    p.add_argument("--scenes", type=c.str_list, default=DEFAULT_SCENES,
                   help="comma-separated: names in scenes/, engine or textured (bench/scenes/), or xi scene files")
    p.add_argument("--resolution", default="128x128")
    p.add_argument("--spps", type=c.int_list, default=[1, 4, 16, 64, 256], help="spp of the uniform and denoised modes")
    p.add_argument("--thresholds", type=lambda s: [float(v) for v in s.split(",")], default=[0.3, 0.1, 0.03, 0.01],
                   help="xi's --noise-threshold values (relative standard error) of the adaptive modes")
    p.add_argument("--cycles-thresholds", type=lambda s: [float(v) for v in s.split(",")],
                   help="Cycles' adaptive_threshold values; unset: --thresholds (Cycles' measure of noise differs)")
    p.add_argument("--adaptive-max-spp", type=int, help="spp cap of the adaptive modes; unset: the largest --spps")
    p.add_argument("--min-spp", type=int,
                   help="xi's --min-spp and Cycles' adaptive_min_samples; unset: each one's default")
    p.add_argument("--ref-spp", type=int, default=4096, help="spp of each renderer's reference (cached in bench/refs)")
    p.add_argument("--refs", default=str(c.REFS), help="folder of the cached references")
    p.add_argument("--runs", type=int, default=3, help="renders of each point (seeds 1, 2, ...); medians")
    p.add_argument("--renderers", type=c.str_list, default=["xi", "mitsuba", "cycles"], help="comma-separated")
    p.add_argument("--modes", type=c.str_list, default=[],
                   help="only these modes: names (uniform, adaptive, ...) or renderer-mode (cycles-oidn, "
                        "mitsuba-ldsampler, ...); unset: all")
    p.add_argument("--xi-sampler", help="xi's --sampler; unset: the scene's, else sobol")
    p.add_argument("--mitsuba-variant", default="llvm_ad_rgb")
    p.add_argument("--no-flip", action="store_true", help="skip HDR-FLIP even where flip-evaluator is installed")
    p.add_argument("--worker-timeout", type=float, default=1800, help="seconds a Mitsuba or Cycles request may take")
    a = p.parse_args()
    a.cycles_thresholds = a.cycles_thresholds or a.thresholds
    c.REFS = Path(a.refs).resolve()
    unknown = [r for r in a.renderers if r not in ("xi", "mitsuba", "cycles")]
    if unknown:
        p.error(f"unknown renderers {', '.join(unknown)} (xi, mitsuba, cycles)")
    xi, out_dir = c.find_xi(a.xi), Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    scenes = [Path(c.scene_path(s)) for s in a.scenes]

    with tempfile.TemporaryDirectory(prefix="xi-time-to-error-") as tmp:
        xi_status = xi_modes(xi, tmp, a.min_spp) if "xi" in a.renderers else {}
        workers = {"mitsuba": (None, "not asked for"), "cycles": (None, "not asked for")}
        if "mitsuba" in a.renderers:
            workers["mitsuba"] = start_mitsuba(a)
        if "cycles" in a.renderers:
            workers["cycles"] = start_cycles(a)
        flip = None if a.no_flip else Flip.start(a.worker_timeout)
        machine = c.machine(xi)
        versions = [subprocess.run([str(xi), "--version"], capture_output=True, text=True).stdout.strip()]
        if workers["mitsuba"][0]:
            info = workers["mitsuba"][0]["independent"].info
            versions.append(f"Mitsuba {info['version']} {info['variant']} ({info['threads']} threads)")
        if workers["cycles"][0]:
            info = workers["cycles"][0].info
            versions.append(f"Blender {info['version']} Cycles on {info['device']} (CPU)")
        versions.append(f"flip-evaluator {flip.version}" if flip
                        else "no HDR-FLIP (bash bench/setup-mitsuba.sh installs flip-evaluator into bench/.venv)")
        log("; ".join(versions))
        for mode, why in xi_status.items():
            if why:
                log(f"xi {mode}: {why}")

        all_points, summary = [], []
        for scene in scenes:
            curves, status, floors, points = measure_scene(a, xi, scene, workers, flip, xi_status, tmp)
            all_points += points
            headers, rows, csv_rows = report(scene.stem, a.resolution, curves, status, floors)
            summary += csv_rows
            print(f"\n{scene.stem} {a.resolution}: references of {a.ref_spp} spp, each renderer its own; medians of "
                  f"{a.runs} runs; {machine}")
            c.print_table(headers, rows)
            print("reference floors (each reference's own relMSE): "
                  + ", ".join(f"{r} {c.fmt(f, '.2e')}" for r, f in floors.items()))
            plot(out_dir / f"time_to_error-{scene.stem}.png",
                 f"{scene.stem} {a.resolution}; {'; '.join(versions[:-1])}; {machine}",
                 {k: v for k, v in curves.items()}, floors, flip is not None)
        for w in [*(workers["mitsuba"][0] or {}).values(), workers["cycles"][0]]:
            if w:
                w.close()
        if flip:
            flip.close()

    print("\nt(target): seconds (each renderer's own render clock, see --help) to reach that relMSE, interpolated in "
          "log-log between the measured points around the first crossing; '<' after it: already reached at the "
          "first point (an upper bound), '—' not reached. /xi best: that time over the fastest xi mode's (> 1: "
          "slower than xi). '!': last relMSE within 4x of its reference's own, which inflates it.")
    c.write_csv(out_dir / "time_to_error-points.csv",
                ["scene", "resolution", "renderer", "mode", "sweep", "param", "seed", "seconds", "wall_seconds",
                 "mean_spp", "relmse", "flip"], all_points)
    c.write_csv(out_dir / "time_to_error.csv",
                ["scene", "resolution", "renderer", "mode", "status", "points", "last_spp", "last_seconds",
                 "last_relmse"] + [f"{k}_{t:g}" for t in TARGETS for k in ("seconds_to", "mark", "ratio_to_xi_best")],
                summary)
    print(f"wrote {out_dir / 'time_to_error.csv'}, {out_dir / 'time_to_error-points.csv'} and "
          f"{', '.join(str(out_dir / f'time_to_error-{s.stem}.png') for s in scenes)}")


if __name__ == "__main__":
    main()
