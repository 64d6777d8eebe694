#!/usr/bin/env python3
"""Writes scenes/sky.hdr: a small analytic sky as an equirectangular Radiance RGBE image.

Orientation as the environment light reads it (kernels/shared/environment.h, Mitsuba 3's): +y up,
column x at u = (x + 0.5) / W, row y at v = (y + 0.5) / H (row 0 at the zenith), direction
(sin φ sin θ, cos θ, −cos φ sin θ) with φ = 2πu, θ = πv.

The model, simple and plausible rather than physical:
  - sky (above the horizon): a gradient from a blue zenith to a pale horizon, brightened around the
    sun (a broad forward-scattering glow), scaled to a mean luminance of 1 over the upper hemisphere;
  - ground (below): a flat warm grey of luminance 0.3, blended into the horizon over about 1°;
  - sun: a disc of 1° angular radius at 40° elevation, azimuth φ = 135° (u = 0.375, between +x and
    +z), of uniform radiance chosen so that it gives SUN_TO_SKY times the sky's irradiance on a
    horizontal plane. Texels on the disc's edge are supersampled, so the disc's power does not
    depend on the resolution.
Standard library only. Usage: scripts/make-sky.py [output] (default scenes/sky.hdr).
"""
import math
import os
import sys

W, H = 512, 256
SUN_ELEVATION = math.radians(40.0)
SUN_AZIMUTH = math.radians(135.0)
SUN_RADIUS = math.radians(1.0)
SUN_TO_SKY = 3.0          # the sun's irradiance on a horizontal plane over the sky's
SKY_MEAN_LUMINANCE = 1.0  # over the upper hemisphere, by solid angle
GROUND = (0.34, 0.29, 0.24)  # luminance ≈ 0.3
ZENITH = (0.25, 0.45, 1.0)
HORIZON = (0.95, 0.97, 1.0)
SUN_COLOUR = (1.0, 0.93, 0.82)


def lum(c):
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


def direction(u, v):
    phi, theta = 2.0 * math.pi * u, math.pi * v
    s = math.sin(theta)
    return (math.sin(phi) * s, math.cos(theta), -math.cos(phi) * s)


SUN = (math.sin(SUN_AZIMUTH) * math.cos(SUN_ELEVATION), math.sin(SUN_ELEVATION),
       -math.cos(SUN_AZIMUTH) * math.cos(SUN_ELEVATION))
COS_SUN_RADIUS = math.cos(SUN_RADIUS)


def sky(d):
    """Sky radiance (before normalisation) for a direction with d.y ≥ 0."""
    y = max(d[1], 0.0)
    h = (1.0 - y) ** 3
    cos_gamma = max(-1.0, min(1.0, d[0] * SUN[0] + d[1] * SUN[1] + d[2] * SUN[2]))
    glow = 1.0 + 1.2 * math.exp(-math.acos(cos_gamma) / 0.35)
    return tuple((z * (1.0 - h) + o * h) * glow for z, o in zip(ZENITH, HORIZON))


def smoothstep(a, b, x):
    t = max(0.0, min(1.0, (x - a) / (b - a)))
    return t * t * (3.0 - 2.0 * t)


def cell_solid_angle(y):
    return (math.cos(math.pi * y / H) - math.cos(math.pi * (y + 1) / H)) * 2.0 * math.pi / W


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "sky.hdr"))

    # Sky normalisation: mean luminance over the upper hemisphere (cells above the horizon).
    raw = [[None] * W for _ in range(H)]
    sky_lum = sky_area = 0.0
    for y in range(H):
        dw = cell_solid_angle(y)
        for x in range(W):
            d = direction((x + 0.5) / W, (y + 0.5) / H)
            raw[y][x] = d
            if d[1] > 0.0:
                sky_lum += lum(sky(d)) * dw
                sky_area += dw
    sky_scale = SKY_MEAN_LUMINANCE * sky_area / sky_lum

    # The sun's radiance from the irradiance ratio: E_sun = L_sun · Ω_sun · sin(elevation).
    e_sky = 0.0
    for y in range(H // 2):
        dw = cell_solid_angle(y)
        for x in range(W):
            d = raw[y][x]
            e_sky += lum(sky(d)) * sky_scale * d[1] * dw
    omega_sun = 2.0 * math.pi * (1.0 - COS_SUN_RADIUS)
    sun_lum = SUN_TO_SKY * e_sky / (omega_sun * math.sin(SUN_ELEVATION))
    sun = tuple(c * sun_lum / lum(SUN_COLOUR) for c in SUN_COLOUR)

    near = math.cos(SUN_RADIUS + 2.0 * math.pi / W * 2.0)  # texels that may touch the disc
    n_sub = 16
    pixels = []
    sun_power = total_power = 0.0
    for y in range(H):
        dw = cell_solid_angle(y)
        for x in range(W):
            d = raw[y][x]
            base = tuple(c * sky_scale for c in sky(d))
            t = smoothstep(-0.02, 0.0, d[1])  # ground → sky over about 1°
            c = tuple(g * (1.0 - t) + s * t for g, s in zip(GROUND, base))
            cos_sun = d[0] * SUN[0] + d[1] * SUN[1] + d[2] * SUN[2]
            if cos_sun > near:  # the disc's coverage of this texel's cell, by supersampling in (u, v)
                hits = 0.0
                weight = 0.0
                for j in range(n_sub):
                    vs = (y + (j + 0.5) / n_sub) / H
                    s = math.sin(math.pi * vs)  # solid angle ∝ sin θ du dv
                    for i in range(n_sub):
                        ds = direction((x + (i + 0.5) / n_sub) / W, vs)
                        weight += s
                        if ds[0] * SUN[0] + ds[1] * SUN[1] + ds[2] * SUN[2] >= COS_SUN_RADIUS:
                            hits += s
                cover = hits / weight
                if cover > 0.0:
                    c = tuple(a + cover * b for a, b in zip(c, sun))
                    sun_power += cover * lum(sun) * dw
            total_power += lum(c) * dw
            pixels.append(c)

    # Radiance RGBE, flat (not run-length encoded) scanlines: a flat scanline's first pixel never
    # reads as the RLE marker (2, 2, len < 128) since a normalised pixel has a component ≥ 128.
    data = bytearray()
    data += b"#?RADIANCE\n# made by scripts/make-sky.py\nFORMAT=32-bit_rle_rgbe\n\n"
    data += b"-Y %d +X %d\n" % (H, W)
    for c in pixels:
        m = max(c)
        if m < 1e-32:
            data += bytes((0, 0, 0, 0))
            continue
        mant, e = math.frexp(m)
        scale = mant * 256.0 / m
        data += bytes((min(255, int(c[0] * scale)), min(255, int(c[1] * scale)), min(255, int(c[2] * scale)), e + 128))
    tmp = out + ".tmp"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, out)
    print(f"wrote {out}: {W}x{H}, {len(data)} bytes")
    print(f"sky mean luminance {SKY_MEAN_LUMINANCE} (scale {sky_scale:.4f}), ground luminance {lum(GROUND):.3f}")
    print(f"sun: radius {math.degrees(SUN_RADIUS):.2f} deg, elevation {math.degrees(SUN_ELEVATION):.1f} deg, "
          f"direction ({SUN[0]:.4f}, {SUN[1]:.4f}, {SUN[2]:.4f}), luminance {sun_lum:.1f}")
    print(f"horizontal irradiance (luminance): sky {e_sky:.4f}, sun {SUN_TO_SKY * e_sky:.4f}")
    print(f"sun's share of the power (luminance over the sphere): {sun_power / total_power:.4f}")


if __name__ == "__main__":
    main()
