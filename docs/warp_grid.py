#!/usr/bin/env python3
"""Draws every warp with every sampler using `xi warp` and tiles the pictures into docs/warps.png.

usage: python3 docs/warp_grid.py [--xi build/xi] [-n 1024]
Needs matplotlib (scripts/install-deps.sh --bench installs it).
"""
import argparse
import os
import subprocess
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg
import matplotlib.pyplot as plt

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MAPS = ["square", "disc", "concentric-disc", "sphere", "hemisphere", "cosine-hemisphere"]
SAMPLERS = ["random", "grid", "stratified", "sobol"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--xi", default=os.path.join(ROOT, "build", "xi"))
    ap.add_argument("-n", type=int, default=1024)
    ap.add_argument("-o", default=os.path.join(ROOT, "docs", "warps.png"))
    args = ap.parse_args()
    fig, axes = plt.subplots(len(SAMPLERS), len(MAPS), figsize=(2.2 * len(MAPS), 2.3 * len(SAMPLERS)))
    with tempfile.TemporaryDirectory() as tmp:
        for r, sampler in enumerate(SAMPLERS):
            for c, m in enumerate(MAPS):
                out = os.path.join(tmp, f"{m}-{sampler}.png")
                subprocess.run([args.xi, "warp", "--map", m, "--sampler", sampler, "-n", str(args.n), "-o", out],
                               check=True, stdout=subprocess.DEVNULL)
                ax = axes[r][c]
                ax.imshow(mpimg.imread(out))
                ax.set_xticks([])
                ax.set_yticks([])
                if r == 0:
                    ax.set_title(m, fontsize=9)
                if c == 0:
                    ax.set_ylabel(sampler, fontsize=9)
    fig.suptitle(f"xi warp: {args.n} points per picture, colour = 8x8 stratum of the unit square", fontsize=10)
    fig.tight_layout()
    fig.savefig(args.o, dpi=80)
    print("wrote", args.o)


if __name__ == "__main__":
    main()
