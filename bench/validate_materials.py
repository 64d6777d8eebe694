#!/usr/bin/env python3
"""xi against Mitsuba 3 where their models coincide: block z-tests of the two images.

Each check is a small scene written to --out/validate/ and converted for Mitsuba by bench/mitsuba_scene.py
from `xi export`: (textured-quad) bilinear sRGB textures with repeat and mirror wrapping and a texture
transform, on diffuse quads under the sky; (diffuse-sky, diffuse-sun) a diffuse sphere and floor under
scenes/sky.hdr turned 60 degrees and under a test map that is dim blue save a small bright sun; (ggx-metal)
a pbr sphere of metallic 1, base colour 1, roughness 0.2 (alpha 0.04) against Mitsuba's roughconductor
(GGX, alpha 0.04, Fresnel 1) under the sky; (punctual) a point and a directional light, no environment, on a
diffuse ball, that metal ball and the floor (Mitsuba's point and directional emitters: W/sr and W/m^2).

xi renders SPP samples per pixel (random sampler) and gives each pixel's variance of the mean (its EXR's
variance layer); Mitsuba (independent sampler) renders K = --mitsuba-runs images of SPP / K each, and its
pixel variance is their sample variance / K. The image is cut into BxB-pixel blocks; per block and channel
z = (mean Mitsuba - mean xi) / sqrt(var Mitsuba + var xi), the variances summed over the block's pixels
(independent); block-channels where neither image varies at all (a uniform background) must agree within
1e-5 instead. Each check passes if, besides, max |z| stays below the two-sided critical value at family-wise level
--alpha with Sidak's correction over its blocks x 3 channels: z_c = Phi^-1(1 - a/2), a = 1 - (1 - alpha)^(1/m).

Runs in the Mitsuba venv (bench/setup-mitsuba.sh): `bench/.venv/bin/python bench/validate_materials.py`."""
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from statistics import NormalDist

sys.dont_write_bytecode = True
sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402
import make_material_scene as mk  # noqa: E402
import mitsuba_scene as ms  # noqa: E402

SKY = str(c.ROOT / "scenes" / "sky.hdr")


def checker_texture(path):
    """16x16 texels, no symmetry: red rises along u, green down v, a blue checker of 4x4 cells, and the
    top-left cell white, so a flip, a mirror or a linear/sRGB mix-up each shows."""
    rows = []
    for y in range(16):
        rows.append([(255, 255, 255) if x < 4 and y < 4 else
                     (16 * x + 8, 16 * y + 8, 220 if (x // 4 + y // 4) % 2 else 30) for x in range(16)])
    mk.write_png(path, 16, 16, rows)


def sun_map(path, w=128, h=64):
    """Dim blue-grey all round, a bright sun of about 2 x 2 texels up and towards +x, +z."""
    rows = []
    for y in range(h):
        rows.append([(4000.0, 3600.0, 3000.0) if 40 <= x < 42 and 16 <= y < 18 else (0.15, 0.2, 0.3)
                     for x in range(w)])
    mk.write_hdr(path, w, h, rows)


def scenes(d):
    """The checks' scene files, written to D."""
    checker_texture(d / "checker.png")
    sun_map(d / "sun.hdr")
    cam = {"position": [0, 1.2, -4], "look_at": [0, 0.6, 0], "up": [0, 1, 0], "fov": 40}
    floor = {"type": "quad", "material": "floor", "vertices": [[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]]}
    ball = lambda mat: {"type": "sphere", "material": mat, "center": [0, 0.7, 0], "radius": 0.7, "subdivisions": 5}
    out = {}
    out["textured-quad"] = {
        "camera": {"position": [0, 0, -3], "look_at": [0, 0, 0], "up": [0, 1, 0], "fov": 45},
        "environment": {"file": SKY, "strength": 1, "rotation": 40},
        "materials": {
            "plain": {"type": "diffuse", "albedo": {"file": "checker.png"}},
            "moved": {"type": "diffuse", "albedo": {"file": "checker.png", "wrap": "mirror", "scale": [1.5, 1.2],
                                                    "rotation": 20, "offset": [0.1, -0.2]}}},
        # seen from -z with +y up: image x runs along -x, so v0 (uv 0,0) at +x, +y is the image's top-left
        "shapes": [{"type": "quad", "material": "plain",
                    "vertices": [[1.1, 1, 0], [0.05, 1, 0], [0.05, -1, 0], [1.1, -1, 0]]},
                   {"type": "quad", "material": "moved",
                    "vertices": [[-0.05, 1, 0], [-1.1, 1, 0], [-1.1, -1, 0], [-0.05, -1, 0]]}]}
    diffuse = {"floor": {"type": "diffuse", "albedo": [0.6, 0.6, 0.6]},
               "ball": {"type": "diffuse", "albedo": [0.8, 0.35, 0.2]}}
    out["diffuse-sky"] = {"camera": cam, "environment": {"file": SKY, "strength": 1, "rotation": 60},
                          "materials": diffuse, "shapes": [floor, ball("ball")]}
    out["diffuse-sun"] = {"camera": cam, "environment": {"file": str(d / "sun.hdr"), "strength": 1, "rotation": 0},
                          "materials": diffuse, "shapes": [floor, ball("ball")]}
    out["ggx-metal"] = {"camera": cam, "environment": {"file": SKY, "strength": 1, "rotation": 60},
                        "materials": {"floor": diffuse["floor"],
                                      "metal": {"type": "pbr", "base_color": [1, 1, 1], "metallic": 1,
                                                "roughness": 0.2}},
                        "shapes": [floor, ball("metal")],
                        # roughconductor is single-scattering GGX
                        "render": {"max_depth": 8, "multiple_scattering": False}}
    # Delta lights alone, black background: a point light (W/sr) and a directional one (W/m^2) on a
    # diffuse ball, a GGX metal ball and the floor. (A spot is left out: Mitsuba's falloff across the
    # cone's edge is linear in the angle, glTF's is not.)
    sphere = lambda mat, x: {"type": "sphere", "material": mat, "center": [x, 0.5, 0], "radius": 0.5,
                             "subdivisions": 5}
    out["punctual"] = {"camera": cam, "background": [0, 0, 0],
                       "lights": [{"type": "point", "position": [1.2, 2.2, -1.4], "color": [1, 0.85, 0.7],
                                   "intensity": 5},
                                  {"type": "directional", "direction": [-0.5, -1, 0.4], "color": [0.6, 0.75, 1],
                                   "intensity": 1.5}],
                       "materials": {"floor": diffuse["floor"], "ball": diffuse["ball"],
                                     "metal": {"type": "pbr", "base_color": [1, 1, 1], "metallic": 1,
                                               "roughness": 0.2}},
                       "shapes": [floor, sphere("ball", -0.65), sphere("metal", 0.65)],
                       "render": {"max_depth": 8, "multiple_scattering": False}}
    paths = {}
    for name, s in out.items():
        s.setdefault("render", {"max_depth": 8})
        paths[name] = d / f"{name}.json"
        paths[name].write_text(json.dumps(s, indent=1) + "\n")
    return paths


def blocks(img, b):
    """Sum over BxB pixel blocks: (H/b, W/b, channels)."""
    h, w, ch = img.shape
    return img[:h // b * b, :w // b * b].reshape(h // b, b, w // b, b, ch).sum(axis=(1, 3))


def check(a, xi, mi, name, scene, d, log):
    import numpy as np
    w, h = c.parse_resolution(a.resolution)
    export = d / f"export-{name}"
    ms.export(xi, scene, export)
    dct, _ = ms.convert(scene, export, w, h, json.loads(scene.read_text())["render"]["max_depth"], "independent")
    if name == "ggx-metal":  # the converter's choice, stated: GGX alpha 0.04, Fresnel 1
        bs = dct["shape-1-smooth"]["bsdf"]["bsdf"]
        log(f"  Mitsuba BSDF: {bs['type']} {bs['distribution']} alpha {bs['alpha']:.4f} material {bs['material']}")
    mscene = mi.load_dict(dct)
    t0 = time.monotonic()
    xi_out = d / f"{name}-xi.exr"
    c.render(xi, scene, xi_out, a.spp, seed=1, resolution=a.resolution, sampler="random")
    layers = dict(mi.Bitmap(str(xi_out)).split())
    x = np.array(layers["<root>"], np.float64)
    xv = np.array(layers["variance"], np.float64)
    t_xi = time.monotonic() - t0
    t0 = time.monotonic()
    k = a.mitsuba_runs
    runs = np.stack([np.array(mi.render(mscene, spp=a.spp // k, seed=100 + i), np.float64) for i in range(k)])
    t_mi = time.monotonic() - t0
    m = runs.mean(axis=0)
    mv = runs.var(axis=0, ddof=1) / k
    mi.util.write_bitmap(str(d / f"{name}-mitsuba.exr"), m.astype(np.float32), write_async=False)
    npix = a.block * a.block
    bx, bm = blocks(x, a.block) / npix, blocks(m, a.block) / npix
    var = (blocks(xv, a.block) + blocks(mv, a.block)) / npix ** 2
    ok = var > 0
    z = np.where(ok, (bm - bx) / np.sqrt(np.where(ok, var, 1)), 0.0)
    tests = int(ok.sum())
    # blocks where neither image varies (a constant background seen directly): equal up to rounding
    exact_bad = int((~ok & (np.abs(bm - bx) > 1e-5 * np.abs(bx) + 1e-12)).sum())
    alpha1 = 1 - (1 - a.alpha) ** (1 / tests)
    crit = NormalDist().inv_cdf(1 - alpha1 / 2)
    zmax = float(np.abs(z).max())
    worst = np.unravel_index(np.abs(z).argmax(), z.shape)
    rel = m.sum(axis=(0, 1)) / x.sum(axis=(0, 1)) - 1
    block_rel = float(np.abs(bm - bx).sum() / bx.sum())
    return dict(check=name, blocks=tests, constant=int((~ok).sum()), exact_bad=exact_bad, zmax=zmax, crit=crit,
                passed=zmax < crit and exact_bad == 0, rel=rel.tolist(),
                block_rel=block_rel, worst=f"block ({worst[1]},{worst[0]}) {'RGB'[worst[2]]}",
                t_xi=t_xi, t_mi=t_mi)


def main():
    p = c.parser(__doc__)
    p.add_argument("--checks", type=c.str_list,
                   default=["textured-quad", "diffuse-sky", "diffuse-sun", "ggx-metal", "punctual"])
    p.add_argument("--resolution", default="64x64")
    p.add_argument("--spp", type=int, default=4096)
    p.add_argument("--mitsuba-runs", type=int, default=16, help="K: Mitsuba renders of SPP/K each, for its variance")
    p.add_argument("--block", type=int, default=8, help="block side in pixels")
    p.add_argument("--alpha", type=float, default=0.01, help="family-wise level per check (Sidak)")
    p.add_argument("--mitsuba-variant", default="llvm_ad_rgb")
    a = p.parse_args()
    if "DRJIT_LIBLLVM_PATH" not in os.environ and a.mitsuba_variant.startswith("llvm"):
        r = subprocess.run(["dpkg", "-L", "libllvm19"], capture_output=True, text=True)
        found = [q for q in r.stdout.split() if "libLLVM" in q and ".so" in q]
        if found:
            os.environ["DRJIT_LIBLLVM_PATH"] = found[0]
    import mitsuba as mi
    mi.set_variant(a.mitsuba_variant)
    mi.set_log_level(mi.LogLevel.Warn)
    xi = c.find_xi(a.xi)
    d = Path(a.out) / "validate"
    d.mkdir(parents=True, exist_ok=True)
    paths = scenes(d)
    log = lambda s: print(s, file=sys.stderr, flush=True)
    rows = []
    for name in a.checks:
        log(f"{name}...")
        r = check(a, xi, mi, name, paths[name], d, log)
        log(f"  xi {r['t_xi']:.1f} s, Mitsuba {r['t_mi']:.1f} s (both with loading)")
        rows.append(r)
    print(f"\nxi against Mitsuba {mi.__version__} {a.mitsuba_variant}: {a.resolution}, {a.spp} spp each "
          f"(Mitsuba {a.mitsuba_runs} x {a.spp // a.mitsuba_runs}), {a.block}x{a.block}-pixel blocks x 3 channels, "
          f"family-wise alpha {a.alpha} per check (Sidak)")
    c.print_table(["check", "tests", "constant", "max |z|", "critical", "result", "Mitsuba/xi - 1 (R, G, B)",
                   "mean |block diff| / mean", "worst"],
                  [[r["check"], r["blocks"], f"{r['constant'] - r['exact_bad']}/{r['constant']}", f"{r['zmax']:.2f}", f"{r['crit']:.2f}", "pass" if r["passed"] else "FAIL",
                    " ".join(f"{q:+.4f}" for q in r["rel"]), f"{r['block_rel']:.4f}", r["worst"]] for r in rows])
    c.write_csv(d / "validate.csv", ["check", "tests", "zmax", "critical", "passed", "rel_r", "rel_g", "rel_b",
                                     "block_rel"],
                [[r["check"], r["blocks"], r["zmax"], r["crit"], r["passed"], *r["rel"], r["block_rel"]] for r in rows])
    print("tests: block-channels z-tested; constant: those where neither image varies (a uniform background), "
          "equal within 1e-5 / all such. Mitsuba/xi - 1: whole image, per channel.")
    return 0 if all(r["passed"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
