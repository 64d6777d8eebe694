#!/usr/bin/env python3
"""Writes kernels/shared/ggx_albedo.h: the directional albedo E(mu, r) of xi's single-scattering GGX
reflection with a Fresnel of 1, and its cosine-weighted average E_avg(r), the tables of the multiple-
scattering energy compensation in kernels/shared/microfacet.h (Kulla and Conty, "Revisiting Physically
Based Shading at Imageworks", SIGGRAPH 2017 course "Physically Based Shading in Theory and Practice").

The BRDF is microfacet.h's: GGX D with alpha = r^2, height-correlated Smith G2, f = D G2 / (4 mu_o mu_i).
E(mu_o) = integral of f mu_i over the hemisphere, estimated with visible-normal samples of h (Heitz 2018),
whose weight is G2 / G1(wo) wherever the reflected direction lies above the surface: a stratified grid of
STRATA^2 samples per entry, the estimate's error well below 1e-3.

Table layout (what microfacet.h's lookups assume): E[j][i] at mu_i = (i + 0.5) / N (cell centres) and
r_j = j / (N - 1), linear in both and clamped at the ends; E_avg[j] = 2 * integral of E(mu) mu dmu over
[0, 1] for that interpolation of row j, so that the compensation lobe integrates to exactly 1 - E(mu_o)
of the table. Row r = 0 is 1 (a mirror loses nothing).

E_F(mu, r, z): the same integral with the microfacet's Fresnel s(wo.h) = (F(wo.h) - F0) / (1 - F0), F the
exact unpolarised Fresnel reflectance of a dielectric of relative ior eta met from outside, F0 its value at
normal incidence: SLICES slices E_F[k][j][i] at z_k = k Z_MAX / (SLICES - 1), z = sqrt((eta - 1) / (eta + 1))
(dense where s changes fastest, near eta = 1), linear in z too. Between slices the lookup stays within a
few 1e-3 of a direct estimate (printed at the end). Standard library only; a few seconds on two cores.
Usage: scripts/make-ggx-albedo.py [output] (default kernels/shared/ggx_albedo.h).
"""
import math
import multiprocessing
import os
import sys

N = 32
STRATA = 48
DELTA_ALPHA = 1e-4  # microfacet.h's XI_DELTA_ALPHA
SLICES = 8          # E_F's slices in z = sqrt((eta - 1) / (eta + 1)), at z = k Z_MAX / (SLICES - 1)
Z_MAX = math.sqrt(0.6)  # eta = 4, the largest ior a scene may give


def slice_eta(k):
    r0 = (k * Z_MAX / (SLICES - 1)) ** 2
    return (1.0 + r0) / (1.0 - r0)


def fresnel_dielectric(c, eta):
    """The unpolarised Fresnel reflectance met at cosine c from outside a dielectric of relative ior eta >= 1."""
    ct = math.sqrt(max(0.0, 1.0 - (1.0 - c * c) / (eta * eta)))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return 0.5 * (rs * rs + rp * rp)


def remapped_fresnel(c, eta):
    """s(c) = (F(c) - F0) / (1 - F0): the Fresnel of eta running from 0 at normal incidence to 1 at grazing."""
    f0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    return min(max((fresnel_dielectric(c, eta) - f0) / (1.0 - f0), 0.0), 1.0)


def lam(x, y, z, a):
    t = a * a * (x * x + y * y) / max(z * z, 1e-30)
    return t / (2.0 * (1.0 + math.sqrt(1.0 + t)))


def visible_normals(wo, a):
    """The STRATA^2 stratified visible normals of GGX alpha A seen from WO (microfacet.h's
    xi_ggx_sample_visible: stretch, sample the half disc, unstretch)."""
    vx, vy, vz = a * wo[0], a * wo[1], wo[2]
    vl = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / vl, vy / vl, vz / vl
    lensq = vx * vx + vy * vy
    if lensq > 0.0:
        inv = 1.0 / math.sqrt(lensq)
        t1 = (-vy * inv, vx * inv, 0.0)
    else:
        t1 = (1.0, 0.0, 0.0)
    t2 = (vy * t1[2] - vz * t1[1], vz * t1[0] - vx * t1[2], vx * t1[1] - vy * t1[0])
    s = 0.5 * (1.0 + vz)
    for i in range(STRATA):
        for j in range(STRATA):
            u1, u2 = (i + 0.5) / STRATA, (j + 0.5) / STRATA
            rr, phi = math.sqrt(u1), 2.0 * math.pi * u2
            p1, p2 = rr * math.cos(phi), rr * math.sin(phi)
            p2 = (1.0 - s) * math.sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2
            p3 = math.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
            nx = t1[0] * p1 + t2[0] * p2 + vx * p3
            ny = t1[1] * p1 + t2[1] * p2 + vy * p3
            nz = t1[2] * p1 + t2[2] * p2 + vz * p3
            hx, hy, hz = a * nx, a * ny, max(nz, 0.0)
            hl = math.sqrt(hx * hx + hy * hy + hz * hz)
            yield hx / hl, hy / hl, hz / hl


def albedo(mu, r, etas):
    """E(mu) and, for each ior of ETAS, E_F(mu)."""
    a = max(r * r, DELTA_ALPHA)
    wo = (math.sqrt(max(0.0, 1.0 - mu * mu)), 0.0, mu)
    lo = lam(*wo, a)
    total = 0.0
    fresnel = [0.0] * len(etas)
    for hx, hy, hz in visible_normals(wo, a):
        d = wo[0] * hx + wo[1] * hy + wo[2] * hz
        wix, wiy, wiz = 2.0 * d * hx - wo[0], 2.0 * d * hy - wo[1], 2.0 * d * hz - wo[2]
        if wiz <= 0.0:
            continue
        weight = (1.0 + lo) / (1.0 + lo + lam(wix, wiy, wiz, a))  # G2 / G1(wo)
        total += weight
        for k, eta in enumerate(etas):
            fresnel[k] += weight * remapped_fresnel(d, eta)
    return total / (STRATA * STRATA), [f / (STRATA * STRATA) for f in fresnel]


def glass_albedo(mu, r, eta):
    """E_glass(mu): the directional albedo of microfacet.h's rough dielectric boundary of relative ior ETA (either
    side: below 1 from inside), reflection and transmission with the exact Fresnel (1 under total internal
    reflection) and no tint. A refracted sample weighs (1 - F) G2 / G1 (no 1/eta^2: microfacet.h's convention)."""
    a = max(r * r, DELTA_ALPHA)
    wo = (math.sqrt(max(0.0, 1.0 - mu * mu)), 0.0, mu)
    lo = lam(*wo, a)
    total = 0.0
    for hx, hy, hz in visible_normals(wo, a):
        d = wo[0] * hx + wo[1] * hy + wo[2] * hz
        if d <= 0.0:
            continue
        sin2_t = (1.0 - d * d) / (eta * eta)
        if sin2_t >= 1.0:
            f, ct = 1.0, 0.0
        else:
            ct = math.sqrt(1.0 - sin2_t)
            rs = (d - eta * ct) / (d + eta * ct)
            rp = (eta * d - ct) / (eta * d + ct)
            f = 0.5 * (rs * rs + rp * rp)
        wrz = 2.0 * d * hz - wo[2]
        if wrz > 0.0:
            total += f * (1.0 + lo) / (1.0 + lo + lam(2.0 * d * hx - wo[0], 2.0 * d * hy - wo[1], wrz, a))
        if f < 1.0:
            k = d / eta - ct  # the refracted direction -wo / eta + (d / eta - ct) h
            wt = (-wo[0] / eta + k * hx, -wo[1] / eta + k * hy, -wo[2] / eta + k * hz)
            if wt[2] < 0.0:
                total += (1.0 - f) * (1.0 + lo) / (1.0 + lo + lam(*wt, a))
    return total / (STRATA * STRATA)


GLASS_N = 16  # E_glass's entries in mu and r


def glass_row(job):
    """Row r_j of E_glass's slice k for the side (0: from outside, eta = slice_eta(k); 1: from inside, its inverse)."""
    side, k, j = job
    eta = slice_eta(k) if side == 0 else 1.0 / slice_eta(k)
    r = j / (GLASS_N - 1)
    return [1.0 if j == 0 else min(glass_albedo((i + 0.5) / GLASS_N, r, eta), 1.0) for i in range(GLASS_N)]


def row(j):
    """Row r_j of E and of every slice of E_F."""
    r = j / (N - 1)
    if j == 0:  # a mirror reflects wo itself: E = 1, E_F = s(mu)
        mus = [(i + 0.5) / N for i in range(N)]
        return [1.0] * N, [[remapped_fresnel(mu, slice_eta(k)) for mu in mus] for k in range(SLICES)]
    both = [albedo((i + 0.5) / N, r, [slice_eta(k) for k in range(SLICES)]) for i in range(N)]
    return [min(e, 1.0) for e, _ in both], [[f[k] for _, f in both] for k in range(SLICES)]


def interpolated(row, mu):
    x = mu * N - 0.5
    i = min(max(int(math.floor(x)), 0), N - 2)
    f = min(max(x - i, 0.0), 1.0)
    return row[i] * (1.0 - f) + row[i + 1] * f


def lookup(table, mu, r, z, n=N):
    """microfacet.h's lookup of E_F (or of one side of E_glass, N = GLASS_N): linear in mu, r and z, clamped."""
    def axis(x, n):
        i = min(max(int(math.floor(x)), 0), n - 2)
        return i, min(max(x - i, 0.0), 1.0)
    i, fx = axis(mu * n - 0.5, n)
    j, fy = axis(r * (n - 1), n)
    k, fz = axis(z / Z_MAX * (SLICES - 1), SLICES)
    def slice_value(kk):
        t = table[kk]
        lo = t[j][i] * (1 - fx) + t[j][i + 1] * fx
        hi = t[j + 1][i] * (1 - fx) + t[j + 1][i + 1] * fx
        return lo * (1 - fy) + hi * fy
    return slice_value(k) * (1 - fz) + slice_value(k + 1) * fz


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "kernels", "shared",
                                                             "ggx_albedo.h")
    with multiprocessing.Pool() as pool:
        rows = pool.map(row, range(N))
        jobs = [(side, k, j) for side in (0, 1) for k in range(SLICES) for j in range(GLASS_N)]
        glass_rows = pool.map(glass_row, jobs)
    glass = [[[glass_rows[(side * SLICES + k) * GLASS_N + j] for j in range(GLASS_N)] for k in range(SLICES)]
             for side in (0, 1)]
    table = [e for e, _ in rows]
    fresnel = [[rows[j][1][k] for j in range(N)] for k in range(SLICES)]
    steps = 4096
    averages = [min(2.0 * sum(interpolated(row, (k + 0.5) / steps) * (k + 0.5) / steps for k in range(steps)) / steps,
                    1.0) for row in table]
    averages[0] = 1.0
    lines = ["// Generated by scripts/make-ggx-albedo.py; do not edit. The directional albedo E(mu, r) of xi's",
             "// single-scattering GGX reflection (Fresnel 1) and its average E_avg(r): the multiple-scattering",
             "// compensation's tables (microfacet.h), and E_F(mu, r, z), the albedo with the Fresnel F of a",
             "// dielectric of ior eta remapped to run from 0 to 1, (F - F0) / (1 - F0), z = sqrt((eta - 1) / (eta + 1)):",
             "// a lobe whose Fresnel runs from f0 to 1 that way reflects f0 E + (1 - f0) E_F, the dielectric layer's",
             "// albedo scaling. E and E_F at mu = (i + 0.5) / %d, r = j / %d (alpha = r^2), E_F's slices at" % (N, N - 1),
             "// z = k z_max / %d, z_max = sqrt(0.6) (ior 4). E_glass(mu, r, z): the directional albedo of the rough" % (SLICES - 1),
             "// dielectric boundary, reflection and transmission (microfacet.h's glass energy compensation), from",
             "// outside (eta = ior) and from inside (1 / ior), each in slices of z as E_F, at mu = (i + 0.5) / %d," % GLASS_N,
             "// r = j / %d. s_avg(z): the remapped Fresnel's cosine-weighted mean on E_F's slices." % (GLASS_N - 1),
             "#ifndef XI_GGX_ALBEDO_H", "#define XI_GGX_ALBEDO_H", '#include "compat.h"', "",
             "#define XI_GGX_ALBEDO_SIZE %d" % N,
             "#define XI_GGX_FRESNEL_SLICES %d" % SLICES,
             "#define XI_GGX_FRESNEL_Z_MAX %.9ff" % Z_MAX,
             "#define XI_GGX_GLASS_SIZE %d" % GLASS_N, "",
             "XI_TABLE float xi_ggx_albedo_table[%d] = {" % (N * N)]
    for r in table:
        lines.append("    " + " ".join("%.6ff," % v for v in r))
    lines += ["};", "", "XI_TABLE float xi_ggx_albedo_average_table[%d] = {" % N]
    for k in range(0, N, 8):
        lines.append("    " + " ".join("%.6ff," % v for v in averages[k:k + 8]))
    lines += ["};", "", "XI_TABLE float xi_ggx_albedo_fresnel_table[%d] = {" % (SLICES * N * N)]
    for k in range(SLICES):
        for r in fresnel[k]:
            lines.append("    " + " ".join("%.6ff," % v for v in r))
    # s_avg(z_k) = 2 * integral of s(mu) mu dmu: the remapped Fresnel's mean, for the layer's multiple scattering.
    steps = 20000
    s_avg = [2.0 * sum(remapped_fresnel((i + 0.5) / steps, slice_eta(k)) * (i + 0.5) / steps for i in range(steps)) / steps
             for k in range(SLICES)]
    lines += ["};", "", "XI_TABLE float xi_ggx_fresnel_average_table[%d] = {" % SLICES,
              "    " + " ".join("%.6ff," % v for v in s_avg)]
    lines += ["};", "", "XI_TABLE float xi_ggx_glass_albedo_table[%d] = {" % (2 * SLICES * GLASS_N * GLASS_N)]
    for side in (0, 1):
        for k in range(SLICES):
            for r in glass[side][k]:
                lines.append("    " + " ".join("%.6ff," % v for v in r))
    lines += ["};", "", "#endif", ""]
    with open(out, "w") as f:
        f.write("\n".join(lines))
    print("wrote %s: E(mu = 1, r = 1) = %.4f, E_avg(r = 0.5) = %.4f, E_avg(r = 1) = %.4f"
          % (out, table[-1][-1], averages[N // 2], averages[-1]))
    # E_F between its slices: the lookup against a direct estimate at iors on no slice.
    worst = 0.0
    for eta in (1.3, 1.5, 2.5):
        z = math.sqrt((eta - 1.0) / (eta + 1.0))
        for mu in (0.05, 0.3, 0.7, 1.0):
            for r in (0.05, 0.3, 0.6, 1.0):
                direct = albedo(mu, r, [eta])[1][0]
                worst = max(worst, abs(lookup(fresnel, mu, r, z) - direct))
    print("E_F's lookup against direct estimates (ior 1.3, 1.5, 2.5): largest difference %.2e" % worst)
    worst = 0.0
    for eta in (1.3, 1.5, 2.5):
        z = math.sqrt((eta - 1.0) / (eta + 1.0))
        for side in (0, 1):
            for mu in (0.05, 0.3, 0.7, 1.0):
                for r in (0.05, 0.3, 0.6, 1.0):
                    direct = glass_albedo(mu, r, eta if side == 0 else 1.0 / eta)
                    worst = max(worst, abs(lookup(glass[side], mu, r, z, GLASS_N) - direct))
    print("E_glass's lookup against direct estimates (ior 1.3, 1.5, 2.5, both sides): largest difference %.2e" % worst)


if __name__ == "__main__":
    main()
