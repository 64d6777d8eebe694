#!/usr/bin/python3
"""Large meshes: how xi's start, memory and speed grow with the triangle count, beside Mitsuba 3.

For each size (--sizes, in millions of triangles) a UV sphere of about that many triangles is written as a
binary PLY (vertices with normals, indexed faces; numpy) and put in the Cornell box's walls and light (a
JSON scene with a "mesh" shape). Each renderer then runs once per size in a fresh process, at --resolution
and --spp:

- xi: `xi render SCENE`; first pass = its "first pass done X s after start", BVH = its `bvh:` line's build
  time, time per sample = its summary's render seconds / spp.
- Mitsuba 3 (bench/.venv, made by bench/setup-mitsuba.sh): the box from `xi export` of the box alone
  (bench/mitsuba_scene.py), the sphere as the same PLY file through Mitsuba's own `ply` loader; first pass =
  from the process's start to the end of its first render of as many spp as xi's first pass holds (scene
  load, Dr.Jit's compilation and the render), time per sample = a second render of --spp / spp.

Peak RSS is each child process's own (GNU time's %M). One untimed run of each at the smallest size
first fills both kernel caches (PoCL's and xi's, Dr.Jit's), so no timed run compiles a kernel from scratch.
Each renderer runs --runs times at each size (default 3), xi and Mitsuba taking turns so that a machine
whose speed drifts through the bench slows both alike, and the table gives, figure by figure, the median
of each one's runs after the first: on a virtual machine that hands freed memory back to its host (the
2-core Firecracker VM these figures come from did, within a minute), a page first written after that
costs a fault in the host, about 2 s per GB against a tenth of that for a page the guest still holds, so
a first run pays for its whole footprint over again and the figures wander with whatever ran before; the
run before it (the other renderer's, of a like footprint) frees that footprint just in time. --runs 1
measures the first runs. Prints a table and writes bench/out/scale.csv and scale.png
(log-log).

  bench/scale.py --xi build/xi                  # 0.1M to 10M triangles
  bench/scale.py --sizes 1,5 --no-mitsuba       # xi alone
  bench/scale.py --sizes 20 --scenes /tmp/s     # 20M (xi's peak near 10 GB); keeps the meshes for reruns
"""
import json
import math
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

VENV = c.ROOT / "bench" / ".venv"
TIME = "/usr/bin/time"  # GNU time (Debian's `time` package), for each child's peak RSS
BOX = c.ROOT / "scenes" / "cornell-box.json"
# The Cornell box's two blocks are left out: the sphere stands where they stood, its radius over a
# third of the room's width.
CENTRE, RADIUS = (278.0, 210.0, 280.0), 200.0
WHITE = [0.725, 0.71, 0.68]


# ---------------------------------------------------------------------------------------------------------
# Scenes.

def sphere_ply(path, triangles):
    """A UV sphere of about TRIANGLES triangles (stacks s, slices 2s: 4s(s - 1) of them), unit normals at its
    vertices, as a binary little-endian PLY; returns the exact count."""
    import numpy as np
    s = max(3, round(math.sqrt(triangles / 4.0)))
    m = 2 * s
    theta = np.pi * np.arange(1, s) / s                     # the s - 1 rings between the poles
    phi = 2.0 * np.pi * np.arange(m) / m
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    n = np.stack([st * np.cos(phi), np.broadcast_to(ct, (s - 1, m)), st * np.sin(phi)], axis=-1).reshape(-1, 3)
    n = np.concatenate([[[0.0, 1.0, 0.0]], n, [[0.0, -1.0, 0.0]]])  # north pole 0, rings, south pole last
    v = np.asarray(CENTRE) + RADIUS * n
    ring = lambda i: 1 + i * m  # noqa: E731 (first vertex of ring i)
    j, j1 = np.arange(m), (np.arange(m) + 1) % m
    faces = [np.stack([np.zeros(m, int), ring(0) + j1, ring(0) + j], axis=1)]  # outward winding
    for i in range(s - 2):
        a, b = ring(i) + j, ring(i) + j1
        cc, d = ring(i + 1) + j, ring(i + 1) + j1
        faces += [np.stack([a, b, d], axis=1), np.stack([a, d, cc], axis=1)]
    south = len(v) - 1
    faces.append(np.stack([np.full(m, south), ring(s - 2) + j, ring(s - 2) + j1], axis=1))
    f = np.concatenate(faces)
    verts = np.empty(len(v), dtype=[(p, "<f4") for p in ("x", "y", "z", "nx", "ny", "nz")])
    for k, p in enumerate("xyz"):
        verts[p] = v[:, k]
        verts["n" + p] = n[:, k]
    rows = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rows["n"], rows["i"] = 3, f
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\n"
              + "".join(f"property float {p}\n" for p in verts.dtype.names)
              + f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as out:
        out.write(header.encode("ascii"))
        out.write(verts.tobytes())
        out.write(rows.tobytes())
    return len(f)


def box_scene(resolution, spp):
    """The Cornell box's walls and light (its blocks left out) as a scene dict."""
    s = json.loads(BOX.read_text())
    w, h = c.parse_resolution(resolution)
    s["film"] = {"width": w, "height": h}
    s["render"] = {"spp": spp, "max_depth": 8, "seed": 1}
    s["shapes"] = s["shapes"][:6]  # floor, light, ceiling, back, left, right
    return s


def write_scenes(folder, sizes, resolution, spp):
    """The box alone (for Mitsuba's walls) and one scene per size; returns (box path, [(millions, triangles,
    scene path, ply path)])."""
    folder.mkdir(parents=True, exist_ok=True)
    box = box_scene(resolution, spp)
    box_path = folder / "box.json"
    box_path.write_text(json.dumps(box, indent=1))
    scenes = []
    for millions in sizes:
        ply = folder / f"sphere-{millions:g}m.ply"
        meta = ply.with_suffix(".count")
        if ply.exists() and meta.exists():
            count = int(meta.read_text())
        else:
            count = sphere_ply(ply, int(millions * 1e6))
            meta.write_text(str(count))
        s = json.loads(json.dumps(box))
        s["shapes"].append({"type": "mesh", "material": "white", "file": ply.name})
        path = folder / f"sphere-{millions:g}m.json"
        path.write_text(json.dumps(s, indent=1))
        scenes.append((millions, count, path, ply))
    return box_path, scenes


# ---------------------------------------------------------------------------------------------------------
# Runs, each in a fresh process.

def peak_of(cmd, env=None):
    """Runs CMD; returns (stdout, stderr, wall s, peak RSS in MB). The peak is GNU time's (%M): a child forked
    straight from this process would start from this process's own high-water mark (the kernel copies it at
    fork), which after writing a large sphere is itself over a gigabyte."""
    with tempfile.NamedTemporaryFile("r", suffix=".rss") as rss:
        t0 = time.monotonic()
        proc = subprocess.run([TIME, "-f", "%M", "-o", rss.name] + [str(x) for x in cmd], capture_output=True,
                              text=True, env=env)
        wall = time.monotonic() - t0
        if proc.returncode != 0:
            sys.exit(f"bench: command failed ({proc.returncode}): {' '.join(map(str, cmd))}\n{proc.stdout}{proc.stderr}")
        peak_kb = int(rss.read().split()[-1])
    return proc.stdout, proc.stderr, wall, peak_kb / 1024.0


def xi_run(xi, scene, out, spp):
    stdout, _, wall, peak = peak_of([xi, "render", scene, "-o", out, "--spp", spp])
    first = re.search(r"first pass done ([\d.]+) s after start", stdout)
    bvh = re.search(r"built in ([\d.]+) ms on (\d+) thread", stdout)
    per_pass = re.search(r"(\d+) spp per pass", stdout)
    summary = c.SUMMARY.search(stdout)
    if not (first and bvh and per_pass and summary):
        sys.exit(f"bench: unexpected output of xi render {scene}:\n{stdout}")
    seconds = c.exr_attributes(out)["renderSeconds"]
    return dict(first=float(first[1]), bvh=float(bvh[1]) * 1e-3, bvh_threads=int(bvh[2]), per_pass=int(per_pass[1]),
                sample=seconds / spp, peak=peak, wall=wall, stdout=stdout)


def medians(runs):
    """Each numeric figure's median over the runs after the first (the only one if there is one)."""
    kept = runs[1:] or runs
    return {k: (statistics.median_low if isinstance(v, int) else statistics.median)([r[k] for r in kept])
            if isinstance(v, (int, float)) else v for k, v in kept[-1].items()}


def mitsuba_env():
    python = VENV / "bin" / "python"
    if not python.exists():
        sys.exit(f"bench: no Mitsuba venv at {VENV}: run bash bench/setup-mitsuba.sh, or pass --no-mitsuba")
    env = dict(os.environ)
    if "DRJIT_LIBLLVM_PATH" not in env:
        import peers
        env["DRJIT_LIBLLVM_PATH"] = peers.libllvm()
    return python, env


def mitsuba_run(box, export, ply, resolution, first_spp, spp, variant):
    python, env = mitsuba_env()
    w, h = c.parse_resolution(resolution)
    req = dict(box=str(box), export=str(export), ply=str(ply), width=w, height=h, first_spp=first_spp, spp=spp,
               variant=variant, started=time.time())
    stdout, stderr, wall, peak = peak_of([python, __file__, "--worker", json.dumps(req)], env)
    lines = [line for line in stdout.splitlines() if line.startswith("{")]
    if not lines:
        sys.exit(f"bench: the Mitsuba worker printed no result:\n{stdout}{stderr}")
    r = json.loads(lines[-1])
    r.update(peak=peak, wall=wall)
    return r


def worker(req):
    """Under bench/.venv's python: loads the box and the sphere, renders FIRST_SPP (timed from the process's
    start, which the driver passed as `started`), then SPP (the time per sample)."""
    started = req["started"]
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # whatever Mitsuba prints goes to stderr
    import mitsuba as mi
    import numpy as np
    import mitsuba_scene as ms
    mi.set_variant(req["variant"])
    mi.set_log_level(mi.LogLevel.Warn)
    d, _ = ms.convert(req["box"], req["export"], req["width"], req["height"], 8, "independent")
    d["sphere"] = {"type": "ply", "filename": req["ply"],
                   "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": ms.rgb(WHITE)}}}
    scene = mi.load_dict(d)
    loaded = time.time() - started
    np.array(mi.render(scene, spp=req["first_spp"], seed=1))  # np.array forces the evaluation
    first = time.time() - started
    t0 = time.perf_counter()
    np.array(mi.render(scene, spp=req["spp"], seed=2))
    sample = (time.perf_counter() - t0) / req["spp"]
    reply.write(json.dumps(dict(loaded=loaded, first=first, sample=sample)) + "\n")


# ---------------------------------------------------------------------------------------------------------

COLUMNS = [("triangles", "triangles", "d"),
           ("xi_first_s", "xi first pass s", ".2f"), ("mi_first_s", "Mitsuba first s", ".2f"),
           ("first_ratio", "first xi/Mi", ".2f"),
           ("xi_peak_mb", "xi peak MB", ".0f"), ("mi_peak_mb", "Mitsuba peak MB", ".0f"),
           ("peak_ratio", "peak xi/Mi", ".2f"),
           ("xi_bvh_s", "xi BVH s", ".2f"), ("mi_load_s", "Mitsuba load s", ".2f"),
           ("xi_ms_per_spp", "xi ms/spp", ".1f"), ("mi_ms_per_spp", "Mitsuba ms/spp", ".1f")]


def main():
    p = c.parser(__doc__.split("\n")[0])
    p.add_argument("--sizes", default="0.1,0.3,1,3,5,10", help="millions of triangles (20 is optional: slow)")
    p.add_argument("--resolution", default="512x512")
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--no-mitsuba", action="store_true", help="xi alone")
    p.add_argument("--mitsuba-variant", default="llvm_ad_rgb")
    p.add_argument("--scenes", default=None, help="folder for the generated meshes and scenes (default: a "
                                                   "temporary one; kept with this option, so reruns reuse them)")
    p.add_argument("--runs", type=int, default=3,
                   help="runs of each renderer at each size; the medians of all but the first are reported")
    a = p.parse_args()
    xi = c.find_xi(a.xi)
    if not os.access(TIME, os.X_OK):
        sys.exit(f"bench: {TIME} is missing (apt-get install time): it measures each child's peak RSS")
    sizes = [float(s) for s in a.sizes.split(",") if s]
    out_dir = Path(a.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="xi-scale-") as tmp:
        folder = Path(a.scenes) if a.scenes else Path(tmp) / "scenes"
        print(f"writing {len(sizes)} spheres to {folder}", file=sys.stderr)
        box, scenes = write_scenes(folder, sizes, a.resolution, a.spp)
        export = Path(tmp) / "box-export"
        if not a.no_mitsuba:
            import mitsuba_scene as ms
            ms.export(xi, box, export)
        rows = []
        for k, (millions, count, scene, ply) in enumerate(scenes):
            if k == 0:  # untimed: fills the kernel caches
                warm = xi_run(xi, scene, Path(tmp) / "warm.exr", a.spp)
                if not a.no_mitsuba:
                    mitsuba_run(box, export, ply, a.resolution, warm["per_pass"], a.spp, a.mitsuba_variant)
            # Each xi run is followed by Mitsuba's, so that a machine whose speed drifts through the
            # bench slows both alike.
            xi_runs, mi_runs = [], []
            for _ in range(max(1, a.runs)):
                xi_runs.append(xi_run(xi, scene, Path(tmp) / f"xi-{millions:g}m.exr", a.spp))
                if not a.no_mitsuba:
                    mi_runs.append(mitsuba_run(box, export, ply, a.resolution, xi_runs[-1]["per_pass"], a.spp,
                                               a.mitsuba_variant))
            x = medians(xi_runs)
            m = medians(mi_runs) if mi_runs else None
            row = dict(triangles=count + 12, millions=millions, xi_first_s=x["first"], xi_peak_mb=x["peak"],
                       xi_bvh_s=x["bvh"], xi_bvh_threads=x["bvh_threads"], xi_ms_per_spp=1e3 * x["sample"],
                       xi_spp_per_pass=x["per_pass"],
                       mi_first_s=m and m["first"], mi_load_s=m and m["loaded"], mi_peak_mb=m and m["peak"],
                       mi_ms_per_spp=m and 1e3 * m["sample"],
                       first_ratio=m and x["first"] / m["first"], peak_ratio=m and x["peak"] / m["peak"])
            rows.append(row)
            print(f"{count:,} triangles: xi first pass {x['first']:.2f} s, peak {x['peak']:.0f} MB, BVH "
                  f"{x['bvh']:.2f} s" + (f"; Mitsuba first {m['first']:.2f} s, peak {m['peak']:.0f} MB" if m else ""),
                  file=sys.stderr)
    info = (f"{a.resolution}, {a.spp} spp, xi {xi}" + ("" if a.no_mitsuba else f", Mitsuba {a.mitsuba_variant}")
            + f"; first pass: {rows[0]['xi_spp_per_pass']} spp, from the process's start; "
            + (f"medians of runs 2 to {a.runs}" if a.runs > 1 else "one run"))
    print(info)
    c.print_table([h for _, h, _ in COLUMNS], [[c.fmt(r[k], f) for k, _, f in COLUMNS] for r in rows])
    csv_path = out_dir / "scale.csv"
    c.write_csv(csv_path, list(rows[0].keys()), [list(r.values()) for r in rows])
    plot(rows, out_dir / "scale.png", info, not a.no_mitsuba)
    print(f"wrote {csv_path} and {out_dir / 'scale.png'}")


def plot(rows, path, info, mitsuba):
    plt = c.pyplot()
    n = [r["triangles"] for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    for ax, (key, label) in zip(axes, (("first_s", "first pass, s after start"), ("peak_mb", "peak RSS, MB"),
                                       ("ms_per_spp", "ms per spp"))):
        ax.loglog(n, [r["xi_" + key] for r in rows], "o-", label="xi")
        if key == "first_s":
            ax.loglog(n, [r["xi_bvh_s"] for r in rows], "s--", label="xi BVH build")
        if mitsuba:
            ax.loglog(n, [r["mi_" + key] for r in rows], "o-", label="Mitsuba 3")
            if key == "first_s":
                ax.loglog(n, [r["mi_load_s"] for r in rows], "s--", label="Mitsuba load")
        ax.set_xlabel("triangles")
        ax.set_title(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(info, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        worker(json.loads(sys.argv[2]))
    else:
        main()
