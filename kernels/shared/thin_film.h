// KHR_materials_iridescence: the reflectance of a thin dielectric film (ior eta_film, thickness d
// nanometres) over a base of ior eta_base (per channel), seen from a medium of ior 1, after Belcour
// and Barla, "A Practical Extension to Microfacet Theory for the Modeling of Varying Iridescence"
// (SIGGRAPH 2017). The waves reflected at the film's top and after m round trips inside it interfere:
//   R(λ) = R12 + Rs + Σ_m 2 C_m cos(m (2π OPD / λ + φ)),   OPD = 2 eta_film d cos θ2,
//   Rs = T121² R23 / (1 − R12 R23),   C_m = (Rs − T121) (R12 R23)^(m/2),   T121 = 1 − R12,
// for each polarisation (s and p apart, then averaged), R12 and R23 the exact Fresnel reflectances of
// the top and bottom interfaces and φ their phase shifts (0 or π for dielectrics). The cosines are
// integrated against the eye's colour matching functions in closed form, through their Fourier
// transforms fitted by Gaussians (the fit the glTF extension gives); the first three orders (higher
// ones are below 1e-3 for glTF's iors). The sum's RGB is white-balanced so that a flat spectrum is
// RGB white, as the constant terms are.
#ifndef XI_THIN_FILM_H
#define XI_THIN_FILM_H
#include "lanes.h"

// The colour matching functions' Fourier transform at optical path difference opd (nm), in linear
// Rec. 709 over its value at 0 (so 1 at opd 0).
static inline xfloat3 xi_thin_film_sensitivity(xfloat opd) {
  xfloat p = (xfloat)(2.0f * 3.14159265f * 1e-9f) * opd, p2 = p * p;
  // Each Gaussian's amplitude is the fit's a·√(2π var).
  xfloat x = 9.04581e-8f * cos(1.6810e6f * p) * exp(-4.3278e9f * p2) + 1.64408e-8f * cos(2.2399e6f * p) * exp(-4.5282e9f * p2);
  xfloat y = 1.06874e-7f * cos(1.7953e6f * p) * exp(-9.3046e9f * p2);
  xfloat z = 1.06970e-7f * cos(2.2084e6f * p) * exp(-6.6121e9f * p2);
  // XYZ to linear Rec. 709, each row over the row's value at XYZ of opd 0.
  xfloat r = (3.2404542f * x - 1.5371385f * y - 0.4985314f * z) * (1.0f / 1.287929e-7f);
  xfloat g = (-0.9692660f * x + 1.8760108f * y + 0.0415560f * z) * (1.0f / 1.013286e-7f);
  xfloat b = (0.0556434f * x - 0.2040259f * y + 1.0572252f * z) * (1.0f / 9.723453e-8f);
  return make_xfloat3(r, g, b);
}

// The Airy sum above for one polarisation and channel: the reflectances r12 and r23, the sign of the
// round trip's phase (cos φ = ±1) and the sensitivities at OPD, 2 OPD and 3 OPD.
static inline xfloat xi_thin_film_airy(xfloat r12, xfloat r23, xfloat phase_sign, xfloat s1, xfloat s2, xfloat s3) {
  xfloat t121 = 1.0f - r12, r123 = r12 * r23;
  xfloat rs = t121 * t121 * r23 / fmax(1.0f - r123, (xfloat)1e-6f);
  xfloat step = sqrt(r123) * phase_sign;
  xfloat c = (rs - t121) * step, sum = r12 + rs + 2.0f * c * s1;
  c *= step;
  sum += 2.0f * c * s2;
  c *= step;
  return sum + 2.0f * c * s3;
}

// One interface's amplitude reflection coefficients from a medium of ior na to one of nb, at cosines
// ca and cb (Snell's pair): r_s and r_p, by one convention for both interfaces (r_ba = −r_ab), so
// that the sign of −r12 r23 is the round trip's phase.
static inline void xi_thin_film_amplitudes(xfloat na, xfloat nb, xfloat ca, xfloat cb, xfloat* rs, xfloat* rp) {
  *rs = (na * ca - nb * cb) / (na * ca + nb * cb);
  *rp = (nb * ca - na * cb) / (nb * ca + na * cb);
}

// One channel: the base's ior eta_base, the film's top already solved (its cosine cos2, amplitudes
// r12s, r12p) and the sensitivities of this channel.
static inline xfloat xi_thin_film_channel(xfloat eta_film, xfloat eta_base, xfloat cos2, xfloat r12s, xfloat r12p,
                                          xfloat s1, xfloat s2, xfloat s3) {
  xfloat sin3_2 = (eta_film * eta_film) * (1.0f - cos2 * cos2) / (eta_base * eta_base);
  xfloat cos3 = sqrt(fmax(1.0f - sin3_2, (xfloat)0.0f));
  xfloat r23s, r23p;
  xi_thin_film_amplitudes(eta_film, eta_base, cos2, cos3, &r23s, &r23p);
  xfloat sign_s = r12s * r23s > 0.0f ? (xfloat)-1.0f : (xfloat)1.0f;
  xfloat sign_p = r12p * r23p > 0.0f ? (xfloat)-1.0f : (xfloat)1.0f;
  xfloat r = 0.5f * (xi_thin_film_airy(r12s * r12s, r23s * r23s, sign_s, s1, s2, s3) +
                     xi_thin_film_airy(r12p * r12p, r23p * r23p, sign_p, s1, s2, s3));
  // Under total internal reflection at the base (a base of lower ior at grazing angles) all returns.
  return sin3_2 >= 1.0f ? (xfloat)1.0f : clamp(r, (xfloat)0.0f, (xfloat)1.0f);
}

// The film's reflectance at cosine cos1 with the film's normal, per channel. A film thinner than
// 1 nm fades to none (its ior towards 1), where the wave optics above no longer hold.
static inline xfloat3 xi_thin_film_fresnel(xfloat cos1, xfloat eta_film, xfloat thickness, xfloat3 eta_base) {
  cos1 = clamp(cos1, (xfloat)0.0f, (xfloat)1.0f);
  xfloat fade = clamp(thickness, (xfloat)0.0f, (xfloat)1.0f);
  eta_film = 1.0f + (eta_film - 1.0f) * fade * fade * (3.0f - 2.0f * fade);
  xfloat cos2 = sqrt(fmax(1.0f - (1.0f - cos1 * cos1) / (eta_film * eta_film), (xfloat)0.0f));
  xfloat r12s, r12p;
  xi_thin_film_amplitudes((xfloat)1.0f, eta_film, cos1, cos2, &r12s, &r12p);
  xfloat opd = 2.0f * eta_film * thickness * cos2;
  xfloat3 s1 = xi_thin_film_sensitivity(opd), s2 = xi_thin_film_sensitivity(2.0f * opd),
          s3 = xi_thin_film_sensitivity(3.0f * opd);
  return make_xfloat3(xi_thin_film_channel(eta_film, eta_base.x, cos2, r12s, r12p, s1.x, s2.x, s3.x),
                      xi_thin_film_channel(eta_film, eta_base.y, cos2, r12s, r12p, s1.y, s2.y, s3.y),
                      xi_thin_film_channel(eta_film, eta_base.z, cos2, r12s, r12p, s1.z, s2.z, s3.z));
}

// The ior whose normal-incidence reflectance from a medium of ior 1 is f0 (< 1), per channel.
static inline xfloat3 xi_ior_of_f0(xfloat3 f0) {
  xfloat x = sqrt(clamp(f0.x, (xfloat)0.0f, (xfloat)0.9999f)), y = sqrt(clamp(f0.y, (xfloat)0.0f, (xfloat)0.9999f)),
         z = sqrt(clamp(f0.z, (xfloat)0.0f, (xfloat)0.9999f));
  return make_xfloat3((1.0f + x) / (1.0f - x), (1.0f + y) / (1.0f - y), (1.0f + z) / (1.0f - z));
}

#endif
