#!/usr/bin/python3
"""Across processes: `xi render` as one process against `mpirun -np P xi render` (P ranks, each rendering every
P-th row on its own device, rank 0 gathering the film state at the end). Four parts, each interleaved:

  scaling  strong scaling: the same scene, resolution and spp as 1 process (all cores) and as P ranks; median
           wall seconds (the whole command, mpirun included), render seconds (rank 0's clock: the passes, not
           the waits between them), Msamples/s, speedup and parallel efficiency, the gather seconds.
  gather   the reduction per frame size: P ranks at 1 spp; the "film state gathered" seconds and MB.
  pass     seconds per pass (--samples-per-pass 1) at one frame size: 1 process, 1 process on one rank's share
           (its rows and its cores, POCL_MAX_PTHREAD_COUNT = cores / P), and P ranks.
  tiny     the per-pass agreement cost: the same three at a tiny frame and two spp; the slope of (wall - render)
           seconds against passes is the time outside the passes, per pass; P ranks minus 1 process is the
           allreduce before each pass, including any wait for the slower rank.

Needs a built xi with MPI (XI_WITH_MPI, on when CMake finds an MPI) and mpirun (Open MPI:
scripts/install-deps.sh). As root it sets OMPI_ALLOW_RUN_AS_ROOT(_CONFIRM); beyond the cores it adds
--oversubscribe. Writes mpi_scaling.csv (every run) and mpi_scaling.json (the tables)."""
import json
import os
import resource
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

# 512x512, 64 spp, 5.35 s, 1.55 Msamples/s, 5.85 Mrays/s[, 2 processes]
SUMMARY = re.compile(r"^(\d+)x(\d+), (\d+) spp, ([\d.]+) s, ([\d.]+) Msamples/s, ([\d.]+) Mrays/s"
                     r"(?:, (\d+) processes)?$", re.M)
GATHERED = re.compile(r"^film state gathered from (\d+) processes: ([\d.]+) MB in ([\d.]+) s$", re.M)
PER_PASS = re.compile(r"^paths in flight: (\d+), (\d+) spp per pass", re.M)
DEVICE = re.compile(r"^device: (.*)$", re.M)
PARTS = ("scaling", "gather", "pass", "tiny")


class Runner:
    """Runs xi as one process or under mpirun and parses what rank 0 prints."""

    def __init__(self, xi, mpirun, ranks, mpirun_args, tmp):
        self.xi, self.mpirun, self.ranks, self.tmp = xi, mpirun, ranks, Path(tmp)
        self.cores = len(os.sched_getaffinity(0))
        self.mpi_cmd = [mpirun, "-np", str(ranks)] + (["--oversubscribe"] if ranks > self.cores else []) + mpirun_args
        self.env = dict(os.environ)
        if os.geteuid() == 0:  # Open MPI refuses root without these
            self.env.setdefault("OMPI_ALLOW_RUN_AS_ROOT", "1")
            self.env.setdefault("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        self.devices = {}
        self._warm = set()

    def share_threads(self):
        """The PoCL threads one rank gets on this host (xi's own rule: cores / ranks on the host)."""
        return max(1, self.cores // self.ranks)

    def render(self, config, scene, resolution, spp, samples_per_pass=None, warm_up=True):
        """One render. config: '1' (one process, every core), 'share' (one process on one rank's rows and
        cores: the resolution's height / ranks, POCL_MAX_PTHREAD_COUNT = cores / ranks) or 'mpi'. With
        warm_up, the first render of each (config, scene, resolution, spp per pass) is preceded by an
        untimed one of the same passes at fewer spp (PoCL compiles work-group functions in the first launch
        of a size)."""
        w, h = c.parse_resolution(resolution)
        if config == "share":
            h = max(1, h // self.ranks)
        key = (config, str(scene), w, h, samples_per_pass)
        if warm_up and key not in self._warm:
            self._warm.add(key)
            self.render(config, scene, resolution, min(spp, 4 if samples_per_pass is None else samples_per_pass),
                        samples_per_pass, warm_up=False)
        out = self.tmp / f"{config}.exr"
        cmd = [self.xi, "render", c.scene_path(str(scene)), "-o", out, "--spp", spp, "--seed", 1,
               "--resolution", f"{w}x{h}"]
        if samples_per_pass is not None:
            cmd += ["--samples-per-pass", samples_per_pass]
        env = dict(self.env)
        if config == "mpi":
            cmd = self.mpi_cmd + cmd
        elif config == "share":
            env["POCL_MAX_PTHREAD_COUNT"] = str(self.share_threads())
        cmd = [str(x) for x in cmd]
        ru0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.monotonic()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall, ru1 = time.monotonic() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
        # CPU seconds of the command and everything it waited for (mpirun reaps its ranks): less sensitive than
        # wall time to other work on the machine, and it shows MPI's busy polling
        cpu = (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime)
        if proc.returncode != 0:
            sys.exit(f"bench: command failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stdout}{proc.stderr}")
        text = proc.stdout
        sums = SUMMARY.findall(text)
        if not sums:
            sys.exit(f"bench: no summary line in the output of {' '.join(cmd)}:\n{text}{proc.stderr}")
        gathered = GATHERED.search(text)
        if config == "mpi":
            if len(sums) > 1 or not gathered:
                sys.exit(f"bench: under mpirun, xi rendered as {len(sums)} independent process(es) instead of one team "
                         f"of {self.ranks}: {self.xi} was built without MPI. Install Open MPI (scripts/install-deps.sh: "
                         f"libopenmpi-dev openmpi-bin), then reconfigure and rebuild (cmake -S . -B build && cmake "
                         f"--build build --target xi; XI_WITH_MPI is on by default).")
            if int(gathered[1]) != self.ranks:
                sys.exit(f"bench: asked for {self.ranks} ranks, xi reports {gathered[1]} processes:\n{text}")
        m = sums[0]
        attrs = c.exr_attributes(out)
        seconds = attrs["renderSeconds"]  # not rounded to 0.01 s like the summary line
        per_pass = PER_PASS.search(text)
        spp_per_pass = int(per_pass[2]) if per_pass else 0
        if config not in self.devices and DEVICE.search(text):
            self.devices[config] = DEVICE.search(text)[1]
        return dict(config=config, scene=Path(c.scene_path(str(scene))).stem, width=w, height=h, spp=spp,
                    processes=self.ranks if config == "mpi" else 1, spp_per_pass=spp_per_pass,
                    passes=-(-spp // spp_per_pass) if spp_per_pass else 0,
                    threads=self.share_threads() if config in ("share", "mpi") else self.cores,
                    wall=wall, cpu=cpu, seconds=seconds, msamples=w * h * spp / seconds * 1e-6, mrays=float(m[5]),
                    summary_seconds=float(m[3]), gather_s=float(gathered[3]) if gathered else 0.0,
                    gather_mb=float(gathered[2]) if gathered else 0.0)


def label(runner, config):
    return {"1": "1 process", "share": "1 process, 1 rank's share", "mpi": f"{runner.ranks} ranks"}[config]


def progress(text):
    print(f"  {text}", file=sys.stderr, flush=True)


def scaling(runner, a, runs):
    rows = []
    for scene in a.scenes:
        res = {"1": [], "mpi": []}
        for i in range(a.runs):
            for config in ("1", "mpi")[::1 if i % 2 == 0 else -1]:  # alternate which goes first
                r = runner.render(config, scene, a.resolution, a.spp)
                res[config].append(r)
                runs.append(dict(part="scaling", run=i, **r))
            progress(f"scaling {scene}: run {i + 1}/{a.runs}: 1 process {res['1'][-1]['wall']:.2f} s, "
                     f"{runner.ranks} ranks {res['mpi'][-1]['wall']:.2f} s (wall)")
        base = {k: c.median([r[k] for r in res["1"]]) for k in ("wall", "seconds")}
        for config in ("1", "mpi"):
            rs = res[config]
            m = {k: c.median([r[k] for r in rs]) for k in ("wall", "cpu", "seconds", "msamples", "gather_s")}
            p = rs[0]["processes"]
            rows.append(dict(scene=rs[0]["scene"], config=label(runner, config), processes=p,
                             threads=rs[0]["threads"], spp_per_pass=rs[0]["spp_per_pass"], passes=rs[0]["passes"],
                             wall=m["wall"], wall_range=(min(r["wall"] for r in rs), max(r["wall"] for r in rs)),
                             seconds=m["seconds"], cpu=m["cpu"], msamples=m["msamples"],
                             speedup_wall=base["wall"] / m["wall"], speedup_render=base["seconds"] / m["seconds"],
                             efficiency=base["wall"] / m["wall"] / p, gather_s=m["gather_s"],
                             other_s=m["wall"] - m["seconds"] - m["gather_s"]))
    print(f"\nStrong scaling: {a.resolution}, {a.spp} spp, seed 1, medians of {a.runs} interleaved runs")
    c.print_table(["scene", "config", "P", "threads", "spp/pass", "wall s", "render s", "CPU s", "Msamples/s",
                   "speedup wall", "speedup render", "efficiency", "gather s", "other s"],
                  [[r["scene"], r["config"], r["processes"], r["threads"], r["spp_per_pass"], c.fmt(r["wall"], ".2f"),
                    c.fmt(r["seconds"], ".2f"), c.fmt(r["cpu"], ".2f"), c.fmt(r["msamples"], ".3f"), c.fmt(r["speedup_wall"], ".3f"),
                    c.fmt(r["speedup_render"], ".3f"), c.fmt(r["efficiency"], ".3f"), c.fmt(r["gather_s"], ".3f"),
                    c.fmt(r["other_s"], ".2f")] for r in rows])
    print("  render s: rank 0's clock over its passes (excludes waits for other ranks); other s: wall - render - "
          "gather (process start, mpirun, scene, kernels, the waits before passes, writing the EXR and PNG);\n"
          "  CPU s: user + system seconds of the command and its ranks; speedup = 1 process's median / this median; efficiency = wall speedup / P")
    return rows


def gather(runner, a, runs):
    res = {s: [] for s in a.gather_sizes}
    for i in range(a.gather_runs):
        for size in a.gather_sizes:  # 1 spp: the pass is short, the reduction is what is timed (no warm-up needed)
            r = runner.render("mpi", a.gather_scene, size, 1, warm_up=False)
            res[size].append(r)
            runs.append(dict(part="gather", run=i, **r))
        progress(f"gather: run {i + 1}/{a.gather_runs}: " +
                 ", ".join(f"{s} {res[s][-1]['gather_s']:.3f} s" for s in a.gather_sizes))
    rows = []
    for size in a.gather_sizes:
        rs = res[size]
        w, h = c.parse_resolution(size)
        g, mb = c.median([r["gather_s"] for r in rs]), rs[0]["gather_mb"]
        rows.append(dict(resolution=size, pixels=w * h, mb=mb, gather_s=g,
                         gather_range=(min(r["gather_s"] for r in rs), max(r["gather_s"] for r in rs)),
                         mb_per_s=mb / g if g > 0 else float("nan"), wall=c.median([r["wall"] for r in rs]),
                         seconds=c.median([r["seconds"] for r in rs])))
    print(f"\nReduction per frame size: {runner.ranks} ranks, 1 spp, {Path(c.scene_path(a.gather_scene)).stem}, "
          f"medians of {a.gather_runs}")
    c.print_table(["resolution", "Mpixels", "film MB", "gather s", "min..max", "MB/s", "render s", "wall s"],
                  [[r["resolution"], c.fmt(r["pixels"] * 1e-6, ".3f"), c.fmt(r["mb"], ".1f"),
                    c.fmt(r["gather_s"], ".3f"), f"{r['gather_range'][0]:.3f}..{r['gather_range'][1]:.3f}",
                    c.fmt(r["mb_per_s"], ".0f"), c.fmt(r["seconds"], ".2f"), c.fmt(r["wall"], ".2f")] for r in rows])
    print("  film MB: the whole frame's state (64 bytes/pixel); gather s: rank 0's reading back of its share, "
          f"receiving the other {runner.ranks - 1} share(s) and putting the frame together; MB/s = film MB / gather s")
    return rows


def pass_study(runner, a, runs, part, resolution, spps):
    """Render, wall and outside (= wall - render) seconds per pass of each config at each spp, and the slopes
    between the smallest and the largest spp."""
    configs = ("1", "share", "mpi")
    res = {(cfg, s): [] for cfg in configs for s in spps}
    for i in range(a.pass_runs):
        order = [(cfg, s) for s in spps for cfg in configs]
        for cfg, s in order[::1 if i % 2 == 0 else -1]:
            r = runner.render(cfg, a.pass_scene, resolution, s, samples_per_pass=1)
            res[(cfg, s)].append(r)
            runs.append(dict(part=part, run=i, **r))
        progress(f"{part} {resolution}: run {i + 1}/{a.pass_runs}")
    rows = []
    lo, hi = min(spps), max(spps)
    for cfg in configs:
        med = {s: {k: c.median([r[k] for r in res[(cfg, s)]]) for k in ("wall", "seconds", "cpu")} for s in spps}
        for s in spps:
            med[s]["outside"] = c.median([r["wall"] - r["seconds"] for r in res[(cfg, s)]])
        r0 = res[(cfg, hi)][0]
        row = dict(resolution=resolution, config=label(runner, cfg), share=f"{r0['width']}x{r0['height']}"
                   if cfg != "mpi" else f"{r0['width']}x{r0['height'] // runner.ranks}", threads=r0["threads"],
                   spp=hi, t_pass=med[hi]["seconds"] / hi,
                   msamples_per_rank=r0["width"] * r0["height"] / (runner.ranks if cfg == "mpi" else 1)
                   / (med[hi]["seconds"] / hi) * 1e-6, wall_pass=float("nan"), outside_pass=float("nan"))
        if hi > lo:
            row["wall_pass"] = (med[hi]["wall"] - med[lo]["wall"]) / (hi - lo)
            row["render_pass"] = (med[hi]["seconds"] - med[lo]["seconds"]) / (hi - lo)
            row["outside_pass"] = (med[hi]["outside"] - med[lo]["outside"]) / (hi - lo)
            row["cpu_pass"] = (med[hi]["cpu"] - med[lo]["cpu"]) / (hi - lo)
        rows.append(row)
    if hi > lo:
        one = next(r for r in rows if r["config"] == label(runner, "1"))
        for r in rows:
            r["extra_outside_pass"] = r["outside_pass"] - one["outside_pass"]
    spp_text = f"{lo} and {hi} spp" if hi > lo else f"{hi} spp"
    print(f"\nPer pass: {resolution}, {spp_text}, --samples-per-pass 1 (passes = spp), "
          f"{Path(c.scene_path(a.pass_scene)).stem}, medians of {a.pass_runs}")
    headers = ["config", "rows/rank", "threads", "ms/pass", "Msamples/s/rank"]
    if hi > lo:
        headers += ["wall ms/pass", "CPU ms/pass", "outside µs/pass", "vs 1 process µs/pass"]
    table = []
    for r in rows:
        t = [r["config"], r["share"], r["threads"], c.fmt(r["t_pass"] * 1e3, ".3f"), c.fmt(r["msamples_per_rank"], ".3f")]
        if hi > lo:
            t += [c.fmt(r["wall_pass"] * 1e3, ".3f"), c.fmt(r["cpu_pass"] * 1e3, ".3f"), c.fmt(r["outside_pass"] * 1e6, ".1f"),
                  c.fmt(r["extra_outside_pass"] * 1e6, ".1f")]
        table.append(t)
    c.print_table(headers, table)
    print(f"  ms/pass: rank 0's render seconds / passes at {hi} spp; '1 rank's share': one process on the rows and "
          f"cores one of {runner.ranks} ranks gets (height / {runner.ranks}, POCL_MAX_PTHREAD_COUNT={runner.share_threads()})")
    if hi > lo:
        print(f"  slopes from {lo} to {hi} spp: wall ms/pass (everything), CPU ms/pass (user + system of all ranks), outside µs/pass ((wall - render) per pass: "
              "the loop between passes, for ranks the allreduce and the wait for the slower rank);\n"
              "  vs 1 process: outside µs/pass minus 1 process's, the per-pass agreement cost")
    return rows


def main():
    p = c.parser(__doc__)
    p.add_argument("--parts", type=c.str_list, default=list(PARTS), help="which parts to run: " + ",".join(PARTS))
    p.add_argument("--ranks", type=int, default=2, help="MPI ranks (P) against one process")
    p.add_argument("--mpirun", default="mpirun", help="the MPI launcher (name on the PATH or a path)")
    p.add_argument("--mpirun-args", default="", help="extra mpirun arguments, space-separated (e.g. '--bind-to none')")
    p.add_argument("--scenes", type=c.str_list, default=["cornell-box"], help="scaling scenes (e.g. cornell-box,caustics)")
    p.add_argument("--resolution", default="512x512", help="scaling resolution")
    p.add_argument("--spp", type=int, default=64, help="scaling spp")
    p.add_argument("--runs", type=int, default=3, help="scaling runs of each config, interleaved")
    p.add_argument("--gather-sizes", type=c.str_list, default=["256x256", "512x512", "1920x1080", "3840x2160"],
                   help="frame sizes of the gather part (P ranks, 1 spp)")
    p.add_argument("--gather-runs", type=int, default=3, help="runs of each gather size, interleaved")
    p.add_argument("--gather-scene", default="cornell-box", help="scene of the gather part")
    p.add_argument("--pass-scene", default="cornell-box", help="scene of the pass and tiny parts")
    p.add_argument("--pass-resolution", default="512x512", help="frame size of the pass part")
    p.add_argument("--pass-spp", type=c.int_list, default=[8], help="spp of the pass part (two values: also slopes)")
    p.add_argument("--tiny-resolution", default="16x16", help="frame size of the tiny part (at least P rows)")
    p.add_argument("--tiny-spp", type=c.int_list, default=[100, 2000], help="the two spp (= passes) of the tiny part")
    p.add_argument("--pass-runs", type=int, default=3, help="runs of each config and spp in the pass and tiny parts")
    a = p.parse_args()
    sys.stdout.reconfigure(line_buffering=True)
    if unknown := [x for x in a.parts if x not in PARTS]:
        sys.exit(f"bench: unknown part(s) {','.join(unknown)} (--parts takes {','.join(PARTS)})")
    if a.ranks < 2:
        sys.exit("bench: --ranks must be at least 2")
    if min(a.runs, a.gather_runs, a.pass_runs) < 1:
        sys.exit("bench: runs must be at least 1")
    xi = c.find_xi(a.xi)
    mpirun = shutil.which(a.mpirun)
    if mpirun is not None:  # /bin/mpirun through a /bin -> /usr/bin link: Open MPI takes its prefix from the path
        mpirun = os.path.join(os.path.realpath(os.path.dirname(mpirun)), os.path.basename(mpirun))
    else:
        sys.exit(f"bench: no MPI launcher '{a.mpirun}' on the PATH: install Open MPI (scripts/install-deps.sh installs "
                 f"openmpi-bin and libopenmpi-dev), then reconfigure and rebuild xi so that it links MPI (cmake -S . -B "
                 f"build && cmake --build build --target xi), or pass --mpirun PATH")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()[0]
    t_start = time.monotonic()
    runs, result = [], {}
    with tempfile.TemporaryDirectory(prefix="xi-bench-mpi-") as tmp:
        runner = Runner(xi, mpirun, a.ranks, a.mpirun_args.split(), tmp)
        # Fail early, and clearly, if xi under mpirun is not one team (xi built without MPI).
        runner.render("mpi", "cornell-box", "16x16", 1, warm_up=False)
        if "scaling" in a.parts:
            result["scaling"] = scaling(runner, a, runs)
        if "gather" in a.parts:
            result["gather"] = gather(runner, a, runs)
        if "pass" in a.parts:
            result["pass"] = pass_study(runner, a, runs, "pass", a.pass_resolution, a.pass_spp)
        if "tiny" in a.parts:
            if len(set(a.tiny_spp)) != 2:
                sys.exit("bench: --tiny-spp takes two different spp")
            result["tiny"] = pass_study(runner, a, runs, "tiny", a.tiny_resolution, a.tiny_spp)
    total = time.monotonic() - t_start
    device = runner.devices.get("1") or runner.devices.get("mpi")
    info = dict(machine=f"{runner.cores} cores", device=device, rank_device=runner.devices.get("mpi"), ranks=a.ranks,
                mpirun=" ".join(runner.mpi_cmd), xi=str(xi), load_before=load, total_seconds=total,
                args={k: v for k, v in vars(a).items()})
    print(f"\n{runner.cores} cores, {device}; {' '.join(runner.mpi_cmd)}; load average before {load:.2f}; "
          f"{total:.0f} s in all")
    keys = ["part", "run", "config", "scene", "width", "height", "spp", "processes", "threads", "spp_per_pass",
            "passes", "wall", "cpu", "seconds", "msamples", "mrays", "gather_s", "gather_mb"]
    c.write_csv(out / "mpi_scaling.csv", keys, [[r[k] for k in keys] for r in runs])
    with open(out / "mpi_scaling.json", "w") as f:
        json.dump(dict(info=info, **result), f, indent=1)
    print(f"wrote {out / 'mpi_scaling.csv'} and {out / 'mpi_scaling.json'}")


if __name__ == "__main__":
    main()
