#!/usr/bin/python3
"""Two builds of xi against each other: N alternated runs of each scene with the old and the new `xi`
(who goes first alternates too), medians of the render seconds and Msamples/s, and the ratio of the
medians new / old (< 1: the new build is faster). For host changes, which xi_kernel_ab (two kernel
folders under one host) cannot compare. Each build renders with its own kernels (the ones it was built
with). As a check that both do the same work, the relMSE of the two images of the same seed is printed
beside that of two seeds of the new build."""
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402


def main():
    p = c.parser(__doc__)
    p.add_argument("--old", required=True, help="the xi program to compare against")
    p.add_argument("--scenes", type=c.str_list, default=["cornell-box", "bench/scenes/engine.json"])
    p.add_argument("--resolution", default="512x512")
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--runs", type=int, default=5, help="timed runs of each build, alternated")
    p.add_argument("--seed", type=int, default=1, help="the same for every run")
    a = p.parse_args()
    if not Path(a.old).is_file():
        sys.exit(f"bench: no xi program at {a.old} (--old: the build to compare against)")
    builds = {"old": c.find_xi(a.old), "new": c.find_xi(a.xi)}
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    runs, summary, notes = [], [], []
    with tempfile.TemporaryDirectory(prefix="xi-bench-") as tmp:
        for scene in a.scenes:
            name = Path(c.scene_path(scene)).stem
            results = {b: [] for b in builds}
            images = {b: Path(tmp) / f"{name}-{b}.exr" for b in builds}
            for i in range(a.runs):  # (common.render warms each build up first, untimed)
                for b in (("old", "new") if i % 2 == 0 else ("new", "old")):
                    r = c.render(builds[b], scene, images[b], a.spp, seed=a.seed, resolution=a.resolution)
                    results[b].append(r)
                    runs.append([name, b, i, r["seconds"], r["msamples"], r["mrays"]])
                print(f"  {name}: run {i + 1}/{a.runs}", file=sys.stderr)
            med = {b: {m: c.median([r[m] for r in rs]) for m in ("seconds", "msamples")} for b, rs in results.items()}
            ratio = med["new"]["seconds"] / med["old"]["seconds"]
            for b in builds:
                secs = [r["seconds"] for r in results[b]]
                summary.append([name, b, c.fmt(med[b]["seconds"], ".3f"), f"{min(secs):.3f}-{max(secs):.3f}",
                                c.fmt(med[b]["msamples"], ".3f"), c.fmt(ratio, ".3f") if b == "new" else ""])
            same, noise, warning = c.same_work(builds["new"], scene, images["new"], images["old"], a.spp, a.seed,
                                               a.resolution)
            notes.append(f"{name}: relMSE of the old build's image against the new one's: {same:.3g} (same seed), "
                         f"{noise:.3g} between two seeds of the new build{warning}")

    print(f"\nold: {builds['old']}\nnew: {builds['new']}\n{a.resolution}, {a.spp} spp, seed {a.seed}, {a.runs} "
          f"runs each (alternated, after a warm-up), scene's sampler, {c.machine(builds['new'])}; seconds: render "
          f"time (kernel build excluded), median and range; ratio: new / old median seconds")
    c.print_table(["scene", "build", "seconds", "range", "Msamples/s", "ratio"], summary)
    print("\n".join([""] + notes))
    c.write_csv(out / "builds.csv", ["scene", "build", "run", "seconds", "msamples_per_s", "mrays_per_s"], runs)
    print(f"\nwrote {out / 'builds.csv'} (every run)")


if __name__ == "__main__":
    main()
