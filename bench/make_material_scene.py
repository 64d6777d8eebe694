#!/usr/bin/python3
"""Writes bench/scenes/material.json and its floor texture bench/scenes/material-tiles.png: spheres of
GGX metal (roughness 0.1 to 0.7), a rough dielectric, a half-metal and a textured diffuse one on a textured
floor, lit by the bundled sky (scenes/sky.hdr). Also bench/scenes/material-metals.json, the same with the
dielectric and the half-metal made metals (their colour and roughness kept): every sphere then has a model
Mitsuba 3's roughconductor shares, for equal-error comparisons. Standard library only; also the PNG and Radiance HDR writers
that bench/validate_materials.py uses for its test images."""
import json
import math
import struct
import sys
import zlib
from pathlib import Path

sys.dont_write_bytecode = True
HERE = Path(__file__).resolve().parent


def write_png(path, width, height, pixels):
    """An 8-bit RGB PNG; PIXELS: rows top first, each a list of (r, g, b) bytes."""
    raw = b"".join(b"\0" + bytes(c for px in row for c in px) for row in pixels)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))
    Path(path).write_bytes(png)


def write_hdr(path, width, height, pixels):
    """A Radiance RGBE file of flat scanlines; PIXELS: rows top first, each a list of linear (r, g, b)."""
    data = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + b"-Y %d +X %d\n" % (height, width))
    for row in pixels:
        for c in row:
            m = max(c)
            if m < 1e-32:
                data += bytes(4)
                continue
            mant, e = math.frexp(m)
            scale = mant * 256.0 / m
            data += bytes((min(255, int(c[0] * scale)), min(255, int(c[1] * scale)), min(255, int(c[2] * scale)),
                           e + 128))
    Path(path).write_bytes(bytes(data))


def tiles(n=128):
    """Floor tiles: 4x4 tiles of two warm greys with darker grout and a faint per-tile shade."""
    rows = []
    for y in range(n):
        row = []
        for x in range(n):
            tx, ty = x * 4 // n, y * 4 // n
            fx, fy = (x * 4 % n) / n, (y * 4 % n) / n
            grout = min(fx, fy, 1 - fx, 1 - fy) < 0.03 * 4
            base = (200, 190, 170) if (tx + ty) % 2 == 0 else (110, 120, 140)
            shade = 0.85 + 0.15 * ((tx * 7 + ty * 3) % 5) / 4
            row.append((60, 55, 50) if grout else tuple(int(c * shade) for c in base))
        rows.append(row)
    return rows


def scene(metals_only=False):
    sphere = lambda mat, c, r, sub=5: {"type": "sphere", "material": mat, "center": c, "radius": r,
                                       "subdivisions": sub}
    return {
        "camera": {"position": [0, 2.6, -9.5], "look_at": [0, 0.6, 0], "up": [0, 1, 0], "fov": 36},
        "film": {"width": 512, "height": 512},
        # Like for like: Mitsuba 3's rough conductors are single-scattering GGX.
        "render": {"spp": 64, "max_depth": 8, "multiple_scattering": False},
        "environment": {"file": "../../scenes/sky.hdr", "strength": 0.6, "rotation": 30},
        "materials": {
            "floor": {"type": "diffuse", "albedo": {"file": "material-tiles.png", "scale": [6, 6]}},
            "gold": {"type": "pbr", "base_color": [1.0, 0.78, 0.34], "metallic": 1, "roughness": 0.15},
            "steel": {"type": "pbr", "base_color": [0.9, 0.9, 0.9], "metallic": 1, "roughness": 0.4},
            "copper": {"type": "pbr", "base_color": [0.95, 0.64, 0.54], "metallic": 1, "roughness": 0.7},
            "plastic": {"type": "pbr", "base_color": [0.7, 0.1, 0.08], "metallic": 1 if metals_only else 0,
                        "roughness": 0.3},
            "satin": {"type": "pbr", "base_color": [0.2, 0.4, 0.8], "metallic": 1 if metals_only else 0.5,
                      "roughness": 0.5},
            "tiled": {"type": "diffuse", "albedo": "material-tiles.png"},
        },
        "shapes": [
            {"type": "quad", "material": "floor",
             "vertices": [[-12, 0, -12], [12, 0, -12], [12, 0, 12], [-12, 0, 12]]},
            sphere("gold", [-2.4, 0.8, 0], 0.8),
            sphere("steel", [0, 0.8, 0.6], 0.8),
            sphere("copper", [2.4, 0.8, 0], 0.8),
            sphere("plastic", [-1.3, 0.5, -1.8], 0.5, 4),
            sphere("satin", [1.3, 0.5, -1.8], 0.5, 4),
            sphere("tiled", [0, 0.45, -2.4], 0.45, 4),
        ],
    }


def main():
    write_png(HERE / "scenes" / "material-tiles.png", 128, 128, tiles())
    (HERE / "scenes" / "material.json").write_text(json.dumps(scene(), indent=1) + "\n")
    (HERE / "scenes" / "material-metals.json").write_text(json.dumps(scene(metals_only=True), indent=1) + "\n")
    print(f"wrote {HERE / 'scenes' / 'material.json'}, material-metals.json and material-tiles.png")


if __name__ == "__main__":
    main()
