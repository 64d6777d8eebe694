#!/usr/bin/python3
"""Whether xi's default lane and packet widths are the fastest on this CPU. Each scene is rendered with 8 or 16
paths per generate and shade work item (--lanes) and 8 or 16 rays per packet (--packet-width), the four
combinations alternated --runs times (the order rotating from run to run) after an untimed warm-up each; the
table gives the median render seconds of each and its ratio to the default's, the one `xi render` picks on this
CPU when given neither. Widths change how the work is cut, not what is computed: each image is compared with
the default's (mse 0: the same image, bit for bit; the packet width may change a pixel where a ray meets two
triangles at exactly the same distance, as in the engine's coincident faces).

--isa avx2 measures the code an AVX2 CPU runs, on whatever x86 CPU runs the bench (PoCL's avx2 kernel library,
as peers.py --isa avx2); the default is then an AVX2 CPU's, 16 lanes and packets of 8."""
import itertools
import os
import re
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

WIDTHS = (8, 16)
OPTIONS = re.compile(r"^kernel options: .*; lanes (\d+); .*; packets of (\d+) rays;", re.M)


def widths_args(lanes, packet):
    return ["--lanes", str(lanes), "--packet-width", str(packet)]


def default_widths(xi, scene, out, resolution, sampler, isa):
    """The (lanes, packet width) xi picks when given neither: an AVX2 CPU's under --isa, else this CPU's, read
    from the kernel options a 1-spp render prints with --profile."""
    if isa:
        args = isa["xi_args"]
        return int(args[args.index("--lanes") + 1]), int(args[args.index("--packet-width") + 1])
    r = c.render(xi, scene, out, 1, resolution=resolution, sampler=sampler, warm_up=False, args=["--profile"])
    m = OPTIONS.search(r["stdout"])
    if not m:
        sys.exit(f"bench: no lanes and packet width in xi's kernel options:\n{r['stdout']}")
    return int(m[1]), int(m[2])


def main():
    p = c.parser(__doc__)
    p.add_argument("--scenes", type=c.str_list, default=["cornell-box", "engine", "material", "textured"],
                   help="scene files, or names in scenes/ and the bench's own (engine, material, product, textured)")
    p.add_argument("--resolution", default="512x512")
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--sampler", default="random", help="as peers.py's xi renders")
    p.add_argument("--runs", type=int, default=5, help="timed runs of each combination, alternated")
    p.add_argument("--isa", choices=sorted(c.ISAS), help="measure the code for this instruction set (see above)")
    a = p.parse_args()
    if a.runs < 1 or a.spp < 1:
        p.error("--runs and --spp must be at least 1")
    isa = c.ISAS.get(a.isa, {})
    if isa:
        os.environ["POCL_KERNELLIB_NAME"] = isa["pocl_kernellib"]  # read by every xi this script runs
    xi, out = c.find_xi(a.xi), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    combos = list(itertools.product(WIDTHS, WIDTHS))
    rows, runs, summary = [], [], []
    with tempfile.TemporaryDirectory(prefix="xi-widths-") as tmp:
        default = default_widths(xi, a.scenes[0], Path(tmp) / "options.exr", a.resolution, a.sampler, isa)
        for scene in a.scenes:
            name = Path(c.scene_path(scene)).stem
            images = {w: Path(tmp) / f"{name}-{w[0]}-{w[1]}.exr" for w in combos}
            seconds = {w: [] for w in combos}
            for i in range(a.runs):
                for w in combos[i % len(combos):] + combos[:i % len(combos)]:
                    r = c.render(xi, scene, images[w], a.spp, resolution=a.resolution, sampler=a.sampler,
                                 args=widths_args(*w))
                    seconds[w].append(r["seconds"])
                    runs.append([name, w[0], w[1], i, r["seconds"]])
                print(f"  {name}: run {i + 1}/{a.runs}", file=sys.stderr)
            med = {w: c.median(s) for w, s in seconds.items()}
            best = min(combos, key=med.get)
            for w in combos:
                mse = c.diff(xi, images[w], images[default], "mse")
                rows.append([name, f"{w[0]} / {w[1]}" + (" (default)" if w == default else ""), f"{med[w]:.3f}",
                             f"{min(seconds[w]):.3f}-{max(seconds[w]):.3f}", f"{med[w] / med[default]:.3f}",
                             "*" if w == best else "", f"{mse:.3g}"])
            # Within noise where the fastest one's slowest run is no faster than the default's fastest.
            summary.append((name, best, med[best] / med[default], max(seconds[best]) >= min(seconds[default])))

    print(f"\n{a.resolution}, {a.spp} spp, {a.sampler} sampler, {a.runs} runs each (alternated, after a warm-up), "
          f"{c.machine(xi)}{f', {a.isa} code' if isa else ''}; seconds: render time (kernel build excluded), "
          f"median and range; ratio: median over the default's; mse: the image against the default's")
    c.print_table(["scene", "lanes / packet", "seconds", "range", "ratio", "fastest", "mse"], rows)
    print()
    for name, best, ratio, overlap in summary:
        noise = " (within noise: the ranges overlap)" if overlap else ""
        verdict = ("the default" if best == default
                   else f"{best[0]} lanes, packets of {best[1]}: {ratio:.3f} of the default's time{noise}")
        print(f"{name}: fastest {verdict}")
    c.write_csv(out / "widths.csv", ["scene", "lanes", "packet_width", "run", "seconds"], runs)
    print(f"\nwrote {out / 'widths.csv'} (every run)")


if __name__ == "__main__":
    main()
