#!/usr/bin/env python3
"""Render benchmark for `xi render`: the Cornell box at 512x512, 16 spp, with --profile, N times.

Reports medians (and min..max) of wall seconds, Msamples/s, Mrays/s, the extend stage's Mitems/s
and each stage's total ms and share of the frame, parsed from what `xi render --profile` prints
(host/cli/render.cpp and host/src/render/profile.cpp). Also times loading the kernels from the
binary cache, a cold compile into an empty cache, and, as a reference measured in the same run,
the same render at 256x256 (interleaved with the 512x512 runs, so that drift affects both),
reported as a ratio. Standard library only; builds nothing. Called by bench_render.sh.
"""
import argparse
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile

STAGES = ["generate", "extend", "shade", "shadow", "accumulate"]


def run_xi(xi, args, env=None):
    proc = subprocess.run([xi] + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    if proc.returncode != 0:
        sys.exit(f"bench: `{' '.join([xi] + args)}` failed with exit code {proc.returncode}:\n{proc.stderr}")
    return proc.stdout


def parse(out):
    """The numbers of one `xi render --profile` run."""
    r = {}
    m = re.search(r"^kernels: (loaded from cache|compiled) in ([0-9.]+) s$", out, re.M)
    if not m:
        sys.exit("bench: no 'kernels: ... in X s' line in:\n" + out)
    r["kernels_from_cache"] = m.group(1) == "loaded from cache"
    r["kernel_seconds"] = float(m.group(2))
    m = re.search(r"^device: (.*)$", out, re.M)
    r["device"] = m.group(1) if m else "?"
    # 512x512, 16 spp, 8.43 s, 0.50 Msamples/s, 2.31 Mrays/s
    m = re.search(r"^(\d+)x(\d+), (\d+) spp, ([0-9.]+) s, ([0-9.]+) Msamples/s, ([0-9.]+) Mrays/s$", out, re.M)
    if not m:
        sys.exit("bench: no summary line '<W>x<H>, <N> spp, <S> s, ...' in:\n" + out)
    r["seconds"] = float(m.group(4))
    r["msamples"] = float(m.group(5))
    r["mrays"] = float(m.group(6))
    # The per-stage table: header "stage launches total ms share Mitems/s", one row per stage, then
    # "kernels" and the time outside kernels ("outside", formerly "host+other").
    lines = out.splitlines()
    start = next((i for i, l in enumerate(lines) if l.split()[:4] == ["stage", "launches", "total", "ms"]), None)
    if start is None:
        sys.exit("bench: no per-stage table in the --profile output:\n" + out)
    r["stages"] = {}
    for line in lines[start + 1:]:
        f = line.split()
        if len(f) == 5 and f[0] in STAGES:
            r["stages"][f[0]] = {"launches": int(f[1]), "ms": float(f[2]), "share": float(f[3].rstrip("%")),
                                 "mitems": float(f[4])}
        elif len(f) == 3 and f[0] in ("kernels", "outside", "host+other"):
            r["stages"]["outside" if f[0] == "host+other" else f[0]] = {"ms": float(f[1]),
                                                                        "share": float(f[2].rstrip("%"))}
        else:
            break
    if "extend" not in r["stages"]:
        sys.exit("bench: no extend row in the per-stage table:\n" + out)
    return r


def med(values):
    return statistics.median(values)


def cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "?"


def source_version():
    """The git commit of this checkout, and whether it has uncommitted changes (best effort)."""
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        commit = subprocess.run(["git", "-C", repo, "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", repo, "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return commit + (" with uncommitted changes" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("xi", nargs="?", default="build/xi", help="the xi program (default: build/xi)")
    ap.add_argument("runs", nargs="?", type=int, default=5, help="timed runs per resolution (default: 5)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--resolution", type=int, default=512, help="square film size (default: 512)")
    ap.add_argument("--reference-resolution", type=int, default=256, help="the scaling reference (default: 256)")
    a = ap.parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # progress goes to stderr; keep the order on a terminal
    if a.runs < 1:
        sys.exit("bench: runs must be at least 1")
    xi = os.path.abspath(a.xi)
    if not (os.path.isfile(xi) and os.access(xi, os.X_OK)):
        sys.exit(f"bench: {a.xi} is not an executable (build xi first, or pass its path)")

    load_before = os.getloadavg()[0]
    tmp = tempfile.mkdtemp(prefix="xi_bench_")
    try:
        out_exr = os.path.join(tmp, "bench.exr")

        def render(res, extra=(), env=None):
            return parse(run_xi(xi, ["render", "--spp", str(a.spp), "--resolution", f"{res}x{res}", "--profile",
                                     "-o", out_exr] + list(extra), env))

        # Kernel build: once into an empty cache (a cold compile), then a run that must find them in
        # the normal cache (the first call fills it if it was empty).
        # POCL_KERNEL_CACHE=0: PoCL keeps its own cache of compiled kernels; bypass it too.
        cold_env = dict(os.environ, XI_CACHE_DIR=os.path.join(tmp, "cache"), POCL_KERNEL_CACHE="0")
        cold = parse(run_xi(xi, ["render", "--spp", "1", "--resolution", "8x8", "--profile", "-o", out_exr],
                            cold_env))
        run_xi(xi, ["render", "--spp", "1", "--resolution", "8x8", "-o", out_exr, "--quiet"])
        cached = parse(run_xi(xi, ["render", "--spp", "1", "--resolution", "8x8", "--profile", "-o", out_exr]))
        if not cached["kernels_from_cache"]:
            sys.exit("bench: the kernels were compiled again on the second run: is the cache writable?")

        # Warm-up (page cache, PoCL's per-local-size work-group functions), not counted.
        render(a.reference_resolution)
        big, small = [], []
        for i in range(a.runs):
            big.append(render(a.resolution))
            small.append(render(a.reference_resolution))
            print(f"  run {i + 1}/{a.runs}: {a.resolution}x{a.resolution} {big[-1]['seconds']:.2f} s, "
                  f"{a.reference_resolution}x{a.reference_resolution} {small[-1]['seconds']:.2f} s",
                  file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    def row(name, values, fmt="{:10.3f}"):
        print(f"  {name:<28}" + fmt.format(med(values)) + "  " + fmt.format(min(values)).strip() + " .. " +
              fmt.format(max(values)).strip())

    res, ref = a.resolution, a.reference_resolution
    print()
    print(f"xi render benchmark: scenes/cornell-box.json, {res}x{res}, {a.spp} spp, --profile, {a.runs} run{'s' if a.runs > 1 else ''}")
    print(f"  machine: {platform.node()}, nproc {os.cpu_count()} ({len(os.sched_getaffinity(0))} usable), "
          f"CPU {cpu_model()}")
    print(f"  device:  {big[0]['device']}")
    print(f"  binary:  {xi}")
    print(f"  source:  {source_version()}")
    print(f"  load:    {load_before:.2f} (1-minute load average before the runs; well above 0, other work shared the CPU)")
    print()
    print(f"  {'metric (' + str(res) + 'x' + str(res) + ')':<28}{'median':>10}  min .. max")
    row("seconds", [r["seconds"] for r in big])
    row("Msamples/s", [r["msamples"] for r in big])
    row("Mrays/s (extend + shadow)", [r["mrays"] for r in big])
    row("extend Mitems/s", [r["stages"]["extend"]["mitems"] for r in big])
    print(f"  {'kernels from cache, s':<28}{cached['kernel_seconds']:10.3f}  (one run, 8x8)")
    print(f"  {'kernels compiled cold, s':<28}{cold['kernel_seconds']:10.3f}  (one run, empty XI_CACHE_DIR)")
    print()
    print(f"  {'stage':<12}{'total ms':>10}{'share':>9}{'Mitems/s':>11}   (medians over {a.runs} runs)")
    for name in STAGES + ["kernels", "outside"]:
        vals = [r["stages"].get(name) for r in big]
        if any(v is None for v in vals):
            continue
        mitems = f"{med([v['mitems'] for v in vals]):11.2f}" if "mitems" in vals[0] else ""
        print(f"  {name:<12}{med([v['ms'] for v in vals]):10.1f}{med([v['share'] for v in vals]):8.1f}%{mitems}")
    print()
    t_big, t_small = med([r["seconds"] for r in big]), med([r["seconds"] for r in small])
    pixel_ratio = (res * res) / (ref * ref)
    print(f"  reference measured in the same run: {ref}x{ref}, {a.spp} spp, {a.runs} runs interleaved with the above")
    print(f"  {'seconds':<28}{t_small:10.3f}  {min(r['seconds'] for r in small):.3f} .. "
          f"{max(r['seconds'] for r in small):.3f}")
    row("Msamples/s", [r["msamples"] for r in small])
    row("extend Mitems/s", [r["stages"]["extend"]["mitems"] for r in small])
    print(f"  time ratio {res}/{ref}: {t_big / t_small:.2f} for {pixel_ratio:.0f}x the pixels "
          f"(scaling efficiency {pixel_ratio / (t_big / t_small):.2f}; 1.00 = linear in pixels)")
    print(f"  throughput ratio {res}/{ref}: {med([r['msamples'] for r in big]) / med([r['msamples'] for r in small]):.2f}"
          " (Msamples/s; above 1: the larger waves use the device better)")


if __name__ == "__main__":
    main()
