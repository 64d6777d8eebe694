#!/usr/bin/python3
"""Sampling: RMSE against spp for each sampler (random, grid, stratified, sobol) on the Cornell box, over the
whole image and two crops (a smooth patch of the back wall, a block silhouette against the wall), with the
fitted slope of log RMSE against log spp. Every (sampler, spp) is its own render, since grid and stratified
lay out their sample set for the final spp."""
import math
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

# Crops as fractions of the image, (x0, y0, x1, y1), placed on the Cornell box (64,32,96,52 and 44,50,68,80
# at 128x128): a patch of the back wall right of the tall block, and the tall block's top-right corner where
# its top and right edges stand against the back wall.
SMOOTH = (64 / 128, 32 / 128, 96 / 128, 52 / 128)
EDGE = (44 / 128, 50 / 128, 68 / 128, 80 / 128)
REGIONS = ("whole", "smooth", "edge")


def crop_pixels(frac, w, h):
    return tuple(round(f * s) for f, s in zip(frac, (w, h, w, h)))


def plot(path, table, samplers, crops, preview, title, floor):
    plt = c.pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.4))
    for ax, region in zip(axes, REGIONS):
        for sampler in samplers:
            pts = [(r["spp"], r[region]) for r in table if r["sampler"] == sampler]
            ax.loglog(*zip(*pts), "o-", label=sampler)
        spp0, e0 = next((r["spp"], r[region]) for r in table)
        spps = sorted({r["spp"] for r in table})
        ax.loglog(spps, [e0 * (s / spp0) ** -0.5 for s in spps], "k:", lw=1, label="slope -1/2")
        if floor:
            ax.axhline(floor[region], color="grey", ls="--", lw=1, label="reference's own RMSE (est.)")
        ax.set(title=f"RMSE, {region}" + (f" {crops[region]}" if region in crops else ""), xlabel="spp")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("RMSE")
    axes[0].legend()
    h, w = preview.shape[:2]
    axes[3].imshow(preview, extent=(0, w, h, 0))
    for region, (x0, y0, x1, y1) in crops.items():
        axes[3].add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, color="cyan", lw=1.5))
        axes[3].text(x0, y0 - 1, region, color="cyan", fontsize=9)
    axes[3].set_title("reference and crops")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main():
    p = c.parser(__doc__)
    p.add_argument("--scene", default="cornell-box")
    p.add_argument("--resolution", default="128x128")
    p.add_argument("--spp", type=c.int_list, default=[1, 4, 16, 64, 256], help="spp levels, comma separated")
    p.add_argument("--samplers", type=c.str_list, default=["random", "grid", "stratified", "sobol"])
    p.add_argument("--seeds", type=c.int_list, default=[1, 2, 3],
                   help="seeds per (sampler, spp): RMSE is the root mean square over them, seconds the median")
    p.add_argument("--ref-spp", type=int, default=4096, help="spp of the cached reference")
    p.add_argument("--smooth", type=c.int_list, help="smooth crop x0,y0,x1,y1 (default: back wall patch)")
    p.add_argument("--edge", type=c.int_list, help="edge crop x0,y0,x1,y1 (default: tall block corner)")
    a = p.parse_args()
    xi, out = c.find_xi(a.xi), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    w, h = c.parse_resolution(a.resolution)
    crops = {"smooth": tuple(a.smooth or crop_pixels(SMOOTH, w, h)), "edge": tuple(a.edge or crop_pixels(EDGE, w, h))}
    ref = c.reference(xi, a.scene, a.resolution, a.ref_spp)

    table = []
    with tempfile.TemporaryDirectory(prefix="xi-bench-") as tmp:
        for sampler in a.samplers:
            for spp in a.spp:
                errors, seconds = {k: [] for k in REGIONS}, []
                for seed in a.seeds:
                    img = Path(tmp) / f"{sampler}-{spp}-{seed}.exr"
                    r = c.render(xi, a.scene, img, spp, seed=seed, resolution=a.resolution, sampler=sampler,
                                 reference=ref)
                    seconds.append(r["seconds"])
                    errors["whole"].append(r["rmse"])
                    for region, crop in crops.items():
                        errors[region].append(c.diff(xi, img, ref, "rmse", crop))
                row = dict(sampler=sampler, spp=spp, seconds=c.median(seconds),
                           **{k: math.sqrt(sum(e * e for e in v) / len(v)) for k, v in errors.items()})
                table.append(row)
                print(f"  {sampler:10s} {spp:5d} spp  {row['seconds']:8.3f} s  RMSE {row['whole']:.4g}", file=sys.stderr)
        # The picture for the crops panel: the reference's PNG, or (not committed) the last render's.
        preview = c.pyplot().imread(str(next(f for f in (ref.with_suffix(".png"), img.with_suffix(".png"))
                                             if f.exists())))

    # The reference's own RMSE, estimated from the random sampler's (which falls as spp^-1/2), is a floor:
    # the measured RMSE is about sqrt(true^2 + floor^2).
    top = max(a.spp)
    last = next((r for r in table if r["sampler"] == "random" and r["spp"] == top), None)
    floor = {k: last[k] * math.sqrt(top / a.ref_spp) for k in REGIONS} if last else None
    headers = ["sampler", "spp", "seconds", "RMSE", "RMSE smooth", "RMSE edge"]
    rows = [[r["sampler"], r["spp"], c.fmt(r["seconds"], ".3f")]
            + [c.fmt(r[k], ".5f") + ("!" if floor and r[k] < 2 * floor[k] else "") for k in REGIONS] for r in table]
    print(f"\n{Path(c.scene_path(a.scene)).stem} {a.resolution}, reference {a.ref_spp} spp, seeds {a.seeds} "
          f"(RMSE: root mean square over seeds; seconds: median), crops smooth {crops['smooth']} edge {crops['edge']}")
    c.print_table(headers, rows)
    if floor:
        print(f"reference floor: the reference's own RMSE is about {', '.join(f'{floor[k]:.5f} ({k})' for k in REGIONS)}"
              f" (random's RMSE at {top} spp x sqrt({top}/{a.ref_spp})); '!': within 2x of it, so inflated by it "
              f"and flattening the slopes; a larger --ref-spp lowers it")
    c.write_csv(out / "samplers.csv", ["sampler", "spp", "seconds", "rmse", "rmse_smooth", "rmse_edge"],
                [[r["sampler"], r["spp"], r["seconds"]] + [r[k] for k in REGIONS] for r in table])

    print("\nslope of log RMSE against log spp (least squares over all spp levels)")
    slopes = []
    for sampler in a.samplers:
        mine = [r for r in table if r["sampler"] == sampler]
        slopes.append([sampler] + [c.fmt(c.loglog_slope([r["spp"] for r in mine], [r[k] for r in mine]), ".2f")
                                   for k in REGIONS])
    c.print_table(["sampler", "whole", "smooth", "edge"], slopes)
    title = (f"{Path(c.scene_path(a.scene)).stem} {a.resolution}, reference {a.ref_spp} spp, "
             f"{len(a.seeds)} seed(s), {c.machine(xi)}")
    plot(out / "samplers.png", table, a.samplers, crops, preview, title, floor)
    print(f"\nwrote {out / 'samplers.csv'} and {out / 'samplers.png'}")


if __name__ == "__main__":
    main()
