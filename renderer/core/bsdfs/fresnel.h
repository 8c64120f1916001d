// Fresnel reflectance: the exact dielectric formula (used by DielectricBSDF, where R + T = 1
// must hold exactly for the furnace test) and Schlick's curve with F0/F90 (used by the
// UsdPreviewSurface lobes, because the spec and Storm define them that way).
#pragma once

#include <algorithm>
#include <cmath>

#include "math.h"

namespace tessera {

// Unpolarised reflectance of a smooth interface (pbrt-v4 eq. 9.11).
// cos_i: cosine between the incident direction and the normal; negative means the light
// arrives from the side the normal points away from, so the ratio is inverted.
// eta = n_below / n_above (the side the normal points to is "above").
// Returns 1 on total internal reflection. eta == 1 is an absent interface: 0 everywhere,
// including exactly at grazing where the general formula is 0/0.
inline float FrDielectric(float cos_i, float eta) {
    if (!(eta > 0.f) || eta == 1.f) return 0.f;
    cos_i = std::clamp(cos_i, -1.f, 1.f);
    if (cos_i < 0.f) {
        eta = 1.f / eta;
        cos_i = -cos_i;
    }
    float sin2_i = 1.f - cos_i * cos_i;
    float sin2_t = sin2_i / (eta * eta);
    if (sin2_t >= 1.f) return 1.f;
    float cos_t = std::sqrt(std::max(0.f, 1.f - sin2_t));
    float r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    float r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    return 0.5f * (r_parl * r_parl + r_perp * r_perp);
}

// Normal-incidence reflectance of a dielectric of index `ior` in vacuum.
inline float F0FromIor(float ior) {
    float r = (1.f - ior) / (1.f + ior);
    return r * r;
}

// Schlick's approximation with an explicit grazing value: F0 at normal incidence, F90 at
// grazing. cos_theta is clamped to [0, 1], so callers may pass |cos|.
inline float SchlickWeight(float cos_theta) {
    float m = 1.f - std::clamp(cos_theta, 0.f, 1.f);
    float m2 = m * m;
    return m2 * m2 * m;
}
inline Color FrSchlick(Color f0, Color f90, float cos_theta) {
    return f0 + (f90 - f0) * SchlickWeight(cos_theta);
}
inline float FrSchlick(float f0, float f90, float cos_theta) {
    return f0 + (f90 - f0) * SchlickWeight(cos_theta);
}

}  // namespace tessera
