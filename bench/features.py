#!/usr/bin/python3
"""Kernel specialisation: render time of the kernels compiled for what the scene uses against the kernels
compiled with every feature (--all-features), N interleaved runs each, medians of seconds and Msamples/s and
the speed ratio specialised / all-features. The Cornell box (diffuse only) gains most; the caustics scene
(glass, smooth normals) lacks only the mirror and the lens, so its ratio should be close to 1.
As a check that both do the same work, it compares the two images of the same seed: they should match to
far below the difference between two seeds."""
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

KERNELS = (("specialised", False), ("all-features", True))


def main():
    p = c.parser(__doc__)
    p.add_argument("--scenes", type=c.str_list, default=["cornell-box", "caustics"])
    p.add_argument("--resolution", default="256x256")
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--runs", type=int, default=5, help="timed runs of each kernel set, interleaved")
    p.add_argument("--seed", type=int, default=1, help="the same for every run")
    a = p.parse_args()
    xi, out = c.find_xi(a.xi), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    runs, summary, notes = [], [], []
    with tempfile.TemporaryDirectory(prefix="xi-bench-") as tmp:
        for scene in a.scenes:
            name = Path(c.scene_path(scene)).stem
            results = {k: [] for k, _ in KERNELS}
            images = {k: Path(tmp) / f"{name}-{k}.exr" for k, _ in KERNELS}
            features = {}
            for i in range(a.runs):  # (common.render warms each kernel set up first, untimed)
                for kernels, all_features in KERNELS[::1 if i % 2 == 0 else -1]:  # alternate the order
                    r = c.render(xi, scene, images[kernels], a.spp, seed=a.seed, resolution=a.resolution,
                                 all_features=all_features)
                    features[kernels] = r["features"]
                    results[kernels].append(r)
                    runs.append([name, kernels, i, r["seconds"], r["msamples"], r["mrays"]])
                print(f"  {name}: run {i + 1}/{a.runs}", file=sys.stderr)
            med = {k: {m: c.median([r[m] for r in rs]) for m in ("seconds", "msamples", "mrays")}
                   for k, rs in results.items()}
            ratio = med["specialised"]["msamples"] / med["all-features"]["msamples"]
            # Same seed, same work: the images should match far closer than two seeds of one kernel set do.
            same, noise, warning = c.same_work(xi, scene, images["specialised"], images["all-features"], a.spp, a.seed,
                                               a.resolution)
            for kernels, _ in KERNELS:
                secs = [r["seconds"] for r in results[kernels]]
                m = med[kernels]
                summary.append([name, kernels, features[kernels], c.fmt(m["seconds"], ".3f"),
                                f"{min(secs):.3f}-{max(secs):.3f}", c.fmt(m["msamples"], ".3f"),
                                c.fmt(m["mrays"], ".2f"), c.fmt(m["mrays"] / m["msamples"], ".2f"),
                                c.fmt(ratio, ".3f") if kernels == "specialised" else ""])
            notes.append(f"{name}: speed ratio specialised / all-features {ratio:.3f}; relMSE of the all-features "
                         f"image against the specialised one: {same:.3g} (same seed), {noise:.3g} between two seeds{warning}")

    print(f"\n{a.resolution}, {a.spp} spp, seed {a.seed}, {a.runs} runs each (interleaved, after a warm-up), "
          f"scene's sampler, {c.machine(xi)}; seconds: render time (kernel build excluded), median and range")
    c.print_table(["scene", "kernels", "features compiled", "seconds", "range", "Msamples/s", "Mrays/s",
                   "rays/sample", "ratio"], summary)
    print("\n".join([""] + notes))
    c.write_csv(out / "features.csv", ["scene", "kernels", "run", "seconds", "msamples_per_s", "mrays_per_s"], runs)
    print(f"\nwrote {out / 'features.csv'} (every run)")


if __name__ == "__main__":
    main()
