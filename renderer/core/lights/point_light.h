// A point light (UsdLux SphereLight with treatAsPoint, or radius 0): a delta light, never
// hit by rays; isotropic unless UsdLux ShapingAPI shapes it (a spot light, an IES profile).
#pragma once

#include <cmath>

#include "light.h"
#include "light_shaping.h"

namespace tessera {

// `intensity` in W/sr per channel.
struct PointLight {
    Vec3 position;
    Color intensity;
    LightShaping shaping;

    bool Sample(Vec3 ref, LightSample* out) const {
        Vec3 to_light = position - ref;
        float d2 = LengthSquared(to_light);
        if (!(d2 > 0.f)) return false;
        out->distance = std::sqrt(d2);
        out->wi = to_light / out->distance;
        out->radiance = intensity * shaping.Factor(-out->wi) / d2;  // inverse-square law
        out->pdf = 1.f;
        out->is_delta = true;
        out->n = Vec3(0.f);
        out->p = position;
        out->p_error = 0.f;
        return true;
    }

    // Uniform direction.
    bool SampleEmission(Vec2 u_dir, EmissionSample* out) const {
        float z = 1.f - 2.f * u_dir.x, r = std::sqrt(std::max(0.f, 1.f - z * z)), phi = 2.f * kPi * u_dir.y;
        out->p = position;
        out->wo = Vec3(r * std::cos(phi), r * std::sin(phi), z);
        const Color shaped = intensity * shaping.Factor(out->wo);
        out->beta = shaped * (4.f * kPi);  // I / (1 / 4 pi)
        out->Le = shaped;
        out->pdf_pos = 1.f;
        out->pdf_dir = 1.f / (4.f * kPi);
        out->infinite = false;
        out->delta_light = true;
        return true;
    }

    static float PdfDirection() { return 1.f / (4.f * kPi); }
    static float PdfPosition() { return 1.f; }
};

}  // namespace tessera
