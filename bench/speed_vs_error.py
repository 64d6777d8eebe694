#!/usr/bin/python3
"""Speed against error: for each strategy (sampler, light transport strategy, kernel set) the relMSE against
a cached high-spp reference as a function of render time, up to --max-spp. Reports per strategy the final
spp, seconds, RMSE and relMSE, the efficiency 1 / (relMSE x seconds), the time to reach each target relMSE and
the slope of log relMSE against log seconds.

Where the curve comes from ('mode'): the random and sobol samplers' samples do not depend on the final spp
(sobol is progressive), so one render with --convergence gives the error after every pass ('passes'). Grid
and stratified lay out one set for the final spp, so their intermediate passes are not what a render of that
many spp gives; they get one render per spp of 1, 2, 4, ... up to --max-spp ('ladder').
"""
import math
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

DEFAULT = "random-mis,grid-mis,stratified-mis,sobol-mis,random-nee,random-bsdf,sobol-mis+all"


def parse_strategy(text):
    """'sampler-strategy[+all]', e.g. sobol-mis+all (+all: --all-features)."""
    name, plus, rest = text.partition("+")
    if plus and rest != "all":
        sys.exit(f"bench: strategy {text}: only '+all' may follow the name")
    sampler, _, strategy = name.partition("-")
    return dict(name=text, sampler=sampler, strategy=strategy or "mis", all_features=bool(plus))


def ladder(max_spp):
    spps = [1 << k for k in range(max_spp.bit_length()) if 1 << k <= max_spp]
    return spps + ([max_spp] if spps[-1] != max_spp else [])


def measure(xi, a, s, ref, tmp):
    """The curve of strategy S: a list of points (spp, seconds, rmse, relmse), and its mode."""
    common = dict(resolution=a.resolution, seed=a.seed, sampler=s["sampler"], strategy=s["strategy"],
                  all_features=s["all_features"], reference=ref)
    mode = a.mode if a.mode != "auto" else ("passes" if s["sampler"] in ("random", "sobol") else "ladder")
    if mode == "passes":
        csv = Path(tmp) / f"{s['name']}.csv"
        c.render(xi, a.scene, Path(tmp) / f"{s['name']}.exr", a.max_spp, convergence=csv, **common)
        return [(int(r["spp"]), r["seconds"], r["rmse"], r["relmse"]) for r in c.read_convergence(csv)], mode
    points = []
    for spp in ladder(a.max_spp):
        r = c.render(xi, a.scene, Path(tmp) / f"{s['name']}-{spp}.exr", spp, **common)
        points.append((spp, r["seconds"], r["rmse"], r["relmse"]))
    return points, mode


def time_to(points, target, fit):
    """Seconds to reach relMSE <= TARGET and a mark: interpolated in log-log between the points around the
    first crossing (''), the first point if that is already below ('<'), or extrapolated along the fit ('*')."""
    prev = None
    for spp, t, _, e in points:
        if e <= target:
            if prev is None:
                return t, "<"
            (t0, e0), (t1, e1) = prev, (t, e)
            f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0))), ""
        prev = (t, e)
    a, b = fit
    return (math.exp((math.log(target) - a) / b), "*") if b < 0 else (math.nan, "")


def plot(path, curves, targets, floor, title):
    plt = c.pyplot()
    fig, ax = plt.subplots(figsize=(9, 6))
    for name, (points, mode) in curves.items():
        style = "-" if mode == "passes" else "o-"
        ax.loglog([p[1] for p in points], [p[3] for p in points], style, ms=3, label=f"{name} ({mode})")
    for t in targets:
        ax.axhline(t, color="grey", ls=":", lw=1)
    if floor:
        lo, hi = ax.get_ylim()
        ax.axhspan(min(lo, floor), 4 * floor, color="red", alpha=0.08, label="< 4x reference's own relMSE")
        ax.set_ylim(lo, hi)
    ax.set(xlabel="render seconds", ylabel="relMSE", title=title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main():
    p = c.parser(__doc__)
    p.add_argument("--scene", default="cornell-box")
    p.add_argument("--resolution", default="128x128")
    p.add_argument("--strategies", type=c.str_list, default=DEFAULT.split(","),
                   help="sampler-strategy[+all], comma separated (+all: --all-features)")
    p.add_argument("--max-spp", type=int, default=256)
    p.add_argument("--ref-spp", type=int, default=4096, help="spp of the cached reference")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--targets", type=lambda s: [float(v) for v in s.split(",")], default=[1e-2, 1e-3],
                   help="relMSE targets for the time-to-reach columns")
    p.add_argument("--fit-from", type=int, default=8,
                   help="fit the slope over the points at power-of-two spp >= this")
    p.add_argument("--mode", choices=("auto", "passes", "ladder"), default="auto",
                   help="auto: passes for random and sobol, ladder for the others")
    a = p.parse_args()
    xi, out = c.find_xi(a.xi), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    strategies = [parse_strategy(s) for s in a.strategies]
    ref = c.reference(xi, a.scene, a.resolution, a.ref_spp)

    curves = {}
    with tempfile.TemporaryDirectory(prefix="xi-bench-") as tmp:
        for s in strategies:
            curves[s["name"]] = measure(xi, a, s, ref, tmp)
            spp, t, _, e = curves[s["name"]][0][-1]
            print(f"  {s['name']:16s} {curves[s['name']][1]:7s} {spp} spp  {t:.2f} s  relMSE {e:.3g}", file=sys.stderr)

    # The reference's own error is a floor: estimated from random-mis, whose relMSE falls as 1/spp.
    floor = None
    if "random-mis" in curves:
        spp, _, _, e = curves["random-mis"][0][-1]
        floor = e * spp / a.ref_spp

    rows, table = [], []
    for name, (points, mode) in curves.items():
        spp, seconds, rmse, relmse = points[-1]
        fit_pts = [p for p in points if p[0] >= a.fit_from and p[0] & (p[0] - 1) == 0]
        fit = c.loglog_fit([p[1] for p in fit_pts], [p[3] for p in fit_pts])
        times = [time_to(points, target, fit) for target in a.targets]
        low = floor is not None and relmse < 4 * floor
        rows.append([name, mode, spp, seconds, rmse, relmse, 1 / (relmse * seconds)]
                    + [v for t, mark in times for v in (t, mark)] + [fit[1]])
        table.append([name, mode, spp, c.fmt(seconds, ".3f"), c.fmt(rmse, ".5f"), c.fmt(relmse, ".3e") + "!" * low,
                      c.fmt(1 / (relmse * seconds), ".4g")] + [c.fmt(t, ".3g") + mark for t, mark in times]
                     + [c.fmt(fit[1], ".2f")])

    name = Path(c.scene_path(a.scene)).stem
    machine = c.machine(xi)
    print(f"\n{name} {a.resolution}, up to {a.max_spp} spp, seed {a.seed}; reference {ref.relative_to(c.ROOT)} "
          f"({a.ref_spp} spp); {machine}")
    c.print_table(["strategy", "mode", "spp", "seconds", "RMSE", "relMSE", "1/(relMSE*s)"]
                  + [f"t(relMSE {t:g})" for t in a.targets] + ["slope"], table)
    print(f"\nseconds: render time, kernel build excluded. slope: least squares of log relMSE against log seconds "
          f"over the points at spp {', '.join(str(s) for s in ladder(a.max_spp) if s >= a.fit_from and s & (s - 1) == 0)}"
          f" (-1 is the Monte Carlo rate).\nt(...): seconds to reach the target, interpolated in log-log between the "
          f"points around the first crossing; * not reached by {a.max_spp} spp, extrapolated along the fitted line; "
          f"< already reached at the first point (1 spp).")
    if floor is not None:
        print(f"reference floor: the {a.ref_spp}-spp reference's own relMSE is about {floor:.2e} (random-mis final "
              f"relMSE x {a.max_spp}/{a.ref_spp}); measured relMSE below 4x that ({4 * floor:.2e}) is marked '!' "
              f"and is inflated by it." + "".join(f"\nwarning: target {t:g} is within 4x of the reference floor; "
                                                  f"its times are not trustworthy" for t in a.targets if t < 4 * floor))
    else:
        print("reference floor: not estimated (needs the random-mis strategy)")
    c.write_csv(out / "speed_vs_error.csv",
                ["strategy", "mode", "spp", "seconds", "rmse", "relmse", "efficiency"]
                + [f"{k}_{t:g}" for t in a.targets for k in ("seconds_to", "mark")] + ["slope"], rows)
    c.write_csv(out / "speed_vs_error-points.csv", ["strategy", "mode", "spp", "seconds", "rmse", "relmse"],
                [[n, mode, *pt] for n, (points, mode) in curves.items() for pt in points])
    plot(out / "speed_vs_error.png", curves, a.targets, floor,
         f"{name} {a.resolution}, reference {a.ref_spp} spp\n{machine}")
    print(f"\nwrote {out / 'speed_vs_error.csv'}, {out / 'speed_vs_error-points.csv'} and {out / 'speed_vs_error.png'}")


if __name__ == "__main__":
    main()
