#!/usr/bin/python3
"""Adaptive sampling against uniform sampling, per scene: one adaptive render (--noise-threshold T, at most
--spp samples a pixel), then

- the share of pixels whose true error is above 2T: per pixel, the largest channel's |x - r| over
  sqrt(I^2 + 0.1^2), I the reference's mean intensity (the measure the stop rule estimates), against a
  high-spp reference; for a pixel that stopped with its error at T, a Gaussian error exceeds 2T in about
  5% of cases;
- the relMSE it reaches, and the samples uniform sampling needs for the same relMSE: uniform renders at
  a ladder of spp around the adaptive one's mean, their relMSE interpolated in log-log (relMSE falls as
  1/spp), and the ratio of those samples to the adaptive render's (above 1: adaptive needs fewer).

relMSE as `xi diff` computes it. Default scenes: the Cornell box and a textured glTF box under the
bundled sky (bench/scenes/box-sky.json: most of the frame is environment)."""
import math
import sys
from pathlib import Path

sys.dont_write_bytecode = True
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

try:
    import numpy as np
    import exr  # noqa: E402
except ImportError:
    sys.exit("bench: numpy is missing: scripts/install-deps.sh --bench installs Debian's python3-numpy")

DARK_FLOOR = 0.1  # the stop rule's (host/include/xi/renderer.h, kAdaptiveDarkFloor)


def main():
    p = c.parser(__doc__)
    p.add_argument("--scenes", type=c.str_list, default=["cornell-box", "bench/scenes/box-sky.json"])
    p.add_argument("--resolution", default="128x128")
    p.add_argument("--threshold", type=float, default=0.02)
    p.add_argument("--spp", type=int, default=4096, help="the most samples a pixel takes")
    p.add_argument("--min-spp", type=int, default=16)
    p.add_argument("--ref-spp", type=int, default=16384)
    p.add_argument("--sampler", default="sobol")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    xi = c.find_xi(args.xi)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for scene in args.scenes:
        name = Path(scene).stem
        ref_path = c.reference(xi, scene, args.resolution, args.ref_spp)
        ref = exr.rgb(ref_path)[0]
        image = out / f"adaptive-{name}-{args.resolution}.exr"
        c.run([xi, "render", c.scene_path(scene), "-o", image, "--resolution", args.resolution, "--spp", args.spp,
               "--noise-threshold", args.threshold, "--min-spp", args.min_spp, "--sampler", args.sampler,
               "--seed", args.seed, "--quiet"])
        mean, attrs = exr.rgb(image)
        spp = exr.rgb(image, "spp")[0][..., 0]
        intensity = ref.mean(axis=-1)
        error = np.abs(mean - ref).max(axis=-1) / np.sqrt(intensity ** 2 + DARK_FLOOR ** 2)
        above = float(np.mean(error > 2 * args.threshold))
        relmse = c.diff(xi, image, ref_path, "relmse")
        mean_spp = float(spp.mean())
        # Uniform renders from half the adaptive mean up, until one is below its relMSE.
        ladder = sorted({max(1, round(mean_spp * f)) for f in (0.5, 1, 1.5, 2, 3, 4, 6, 8, 12, 16)})
        uniform = []
        for n in ladder:
            u = out / f"adaptive-{name}-uniform-{n}.exr"
            c.run([xi, "render", c.scene_path(scene), "-o", u, "--resolution", args.resolution, "--spp", n,
                   "--sampler", args.sampler, "--seed", args.seed, "--quiet"])
            uniform.append((n, c.diff(xi, u, ref_path, "relmse")))
            if uniform[-1][1] < relmse and len(uniform) > 1:
                break
        needed = spp_for(uniform, relmse)
        print(f"{name}: adaptive mean {mean_spp:.1f} spp (max {args.spp}), relMSE {relmse:.4e}; uniform: "
              + ", ".join(f"{n} spp {e:.4e}" for n, e in uniform))
        rows.append([name, args.resolution, args.threshold, f"{mean_spp:.1f}", f"{relmse:.3e}",
                     f"{100 * above:.2f}%", "—" if needed is None else f"{needed:.0f}",
                     "—" if needed is None else f"{needed / mean_spp:.2f}"])
    headers = ["scene", "resolution", "T", "adaptive mean spp", "adaptive relMSE", "pixels > 2T",
               "uniform spp for that relMSE", "samples uniform / adaptive"]
    print(f"\nAdaptive sampling, {args.sampler} sampler, --min-spp {args.min_spp}, at most {args.spp} spp; "
          f"references {args.ref_spp} spp; {c.machine(xi)}")
    c.print_table(headers, rows)
    c.write_csv(out / "adaptive.csv", headers, rows)


def spp_for(points, target):
    """The spp at which the uniform relMSE points (spp, relMSE) reach TARGET, interpolated in log-log between
    the two that bracket it; None if none do."""
    for (n0, e0), (n1, e1) in zip(points, points[1:]):
        if e0 >= target >= e1 and e0 > e1:
            t = (math.log(e0) - math.log(target)) / (math.log(e0) - math.log(e1))
            return math.exp(math.log(n0) + t * (math.log(n1) - math.log(n0)))
    return None


if __name__ == "__main__":
    main()
