// The Henyey-Greenstein phase function. Directions are those of propagation: d is the
// direction the light travelled in before scattering (the ray's), wi after it (in a path
// traced from the camera: the direction the next ray is cast along, reversed for light).
// HG depends only on cos theta = d . wi and is symmetric in it, so radiance and
// importance transport share it. g > 0 scatters forward.
#pragma once

#include <cmath>

#include "math.h"

namespace tessera {

inline float HenyeyGreenstein(float cos_theta, float g) {
    const float denom = 1.f + g * g - 2.f * g * cos_theta;
    return (1.f - g * g) / (4.f * kPi * denom * std::sqrt(std::max(denom, 1e-12f)));
}

struct PhaseSample {
    Vec3 wi;
    float pdf = 0.f;  // = the phase function's value: sampling is exact
};

struct HGPhase {
    float g = 0.f;

    float p(Vec3 d, Vec3 wi) const { return HenyeyGreenstein(Dot(d, wi), g); }

    // Inverts HG's cumulative distribution of cos theta (closed form), phi uniform.
    PhaseSample Sample(Vec3 d, Vec2 u) const {
        float cos_theta;
        if (std::abs(g) < 1e-3f) {
            cos_theta = 1.f - 2.f * u.x;
        } else {
            const float s = (1.f - g * g) / (1.f - g + 2.f * g * u.x);
            cos_theta = (1.f + g * g - s * s) / (2.f * g);
        }
        cos_theta = std::clamp(cos_theta, -1.f, 1.f);
        const float sin_theta = std::sqrt(std::max(0.f, 1.f - cos_theta * cos_theta));
        const float phi = 2.f * kPi * u.y;
        const Frame f = Frame::FromZ(d);
        PhaseSample ps;
        ps.wi = Normalize(f.FromLocal({sin_theta * std::cos(phi), sin_theta * std::sin(phi), cos_theta}));
        ps.pdf = HenyeyGreenstein(cos_theta, g);
        return ps;
    }
};

}  // namespace tessera
