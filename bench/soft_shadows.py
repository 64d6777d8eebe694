#!/usr/bin/python3
"""Light transport: the soft shadow of a square occluder under an area light, rendered by each sampler at the
same low spp, side by side (one row per spp, the reference last), with the RMSE of each against a high-spp
reference, over the whole image and over the penumbra. As in the lecture's comparison of pure random, grid
and stratified shadows: grid bands the penumbra, random is noisy, stratified (and sobol) trade the bands for
less noise."""
import sys
import tempfile
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in the repo
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

# The shadow and its penumbra below the occluder, as fractions of the image (x0, y0, x1, y1): 64,104,192,184
# at 256x256.
SHADOW = (64 / 256, 104 / 256, 192 / 256, 184 / 256)


def main():
    p = c.parser(__doc__)
    p.add_argument("--scene", default="soft-shadows")
    p.add_argument("--resolution", default="256x256")
    p.add_argument("--spp", type=c.int_list, default=[4, 16], help="spp levels, comma separated (one row each)")
    p.add_argument("--samplers", type=c.str_list, default=["random", "grid", "stratified", "sobol"])
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--ref-spp", type=int, default=4096, help="spp of the cached reference")
    p.add_argument("--shadow", type=c.int_list, help="penumbra crop x0,y0,x1,y1 (default: around the shadow)")
    a = p.parse_args()
    xi, out = c.find_xi(a.xi), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    w, h = c.parse_resolution(a.resolution)
    shadow = tuple(a.shadow or (round(f * s) for f, s in zip(SHADOW, (w, h, w, h))))
    ref = c.reference(xi, a.scene, a.resolution, a.ref_spp)
    name = Path(c.scene_path(a.scene)).stem

    plt = c.pyplot()
    cols = len(a.samplers) + 1
    fig, axes = plt.subplots(len(a.spp), cols, figsize=(3.2 * cols, 3.8 * len(a.spp)), squeeze=False)
    table = []
    with tempfile.TemporaryDirectory(prefix="xi-bench-") as tmp:
        for row, spp in enumerate(a.spp):
            for col, sampler in enumerate(a.samplers):
                img = Path(tmp) / f"{sampler}-{spp}.exr"
                r = c.render(xi, a.scene, img, spp, seed=a.seed, resolution=a.resolution, sampler=sampler,
                             reference=ref)
                r.update(sampler=sampler, spp=spp, shadow=c.diff(xi, img, ref, "rmse", shadow))
                table.append(r)
                axes[row][col].imshow(plt.imread(str(img.with_suffix(".png"))))
                axes[row][col].set_title(f"{sampler}, {spp} spp\nRMSE {r['rmse']:.4f} (penumbra {r['shadow']:.4f})",
                                         fontsize=9)
        for row in range(len(a.spp)):
            ax = axes[row][-1]
            ax.imshow(plt.imread(str(ref.with_suffix(".png"))))
            x0, y0, x1, y1 = shadow
            ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, color="cyan", lw=1))
            ax.set_title(f"reference, {a.ref_spp} spp\n(cyan: penumbra crop)", fontsize=9)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{name} {a.resolution}, seed {a.seed}, {c.machine(xi)}")
    fig.tight_layout()
    fig.savefig(out / "soft-shadows-samplers.png", dpi=100)

    print(f"\n{name} {a.resolution}, seed {a.seed}, reference {a.ref_spp} spp, penumbra crop {shadow}")
    headers = ["sampler", "spp", "seconds", "RMSE", "relMSE", "RMSE penumbra"]
    rows = [[r["sampler"], r["spp"], r["seconds"], r["rmse"], r["relmse"], r["shadow"]]
            for r in sorted(table, key=lambda r: (a.samplers.index(r["sampler"]), r["spp"]))]
    c.print_table(headers, [[s, n, c.fmt(t, ".3f"), c.fmt(e, ".5f"), c.fmt(m, ".3g"), c.fmt(p, ".5f")]
                            for s, n, t, e, m, p in rows])
    c.write_csv(out / "soft-shadows.csv", ["sampler", "spp", "seconds", "rmse", "relmse", "rmse_penumbra"], rows)
    print(f"\nwrote {out / 'soft-shadows-samplers.png'} and {out / 'soft-shadows.csv'}")


if __name__ == "__main__":
    main()
