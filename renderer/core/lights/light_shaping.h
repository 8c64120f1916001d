// UsdLux ShapingAPI for point lights and one-sided area lights (about their emitting
// normal): a cone with a soft edge, focus, and an IES profile.
// A factor on the light's intensity per emission direction; the light is still sampled
// uniformly (the factor changes what a direction carries, never which directions exist).
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "math.h"

namespace tessera {

// Number of IES samples over the vertical angle 0..180 degrees (1 degree apart).
constexpr int kIesSamples = 181;

struct LightShaping {
    bool enabled = false;
    Vec3 axis{0.f, 0.f, -1.f};  // unit emission axis in world space (the light's -Z)
    float cutoff = kPi;         // cone half angle, radians: nothing beyond it
    float smooth_start = kPi;   // angle where the soft edge starts to fall off
    float focus = 0.f;          // exponent on |cos| off the axis (0: none)
    Color focus_tint{0.f};      // what the focus falloff fades to
    std::vector<float> ies;     // kIesSamples factors over the angle off the axis, or empty

    Color Factor(Vec3 w) const { return FactorAbout(axis, w); }

    // The same about another unit axis: an area light's emitting normal where it emits.
    Color FactorAbout(Vec3 about, Vec3 w) const {
        if (!enabled) return Color(1.f);
        const float c = std::clamp(Dot(about, w), -1.f, 1.f);
        const float theta = std::acos(c);
        if (theta > cutoff) return Color(0.f);
        float f = 1.f;
        if (theta > smooth_start && cutoff > smooth_start) {
            // UsdLux: 1 - smoothstep(smooth_start, cutoff, theta)
            const float t = (theta - smooth_start) / (cutoff - smooth_start);
            f = 1.f - t * t * (3.f - 2.f * t);
        }
        Color out(f);
        if (focus > 0.f) {
            const float p = std::pow(std::fabs(c), focus);
            out = out * (focus_tint + (Color(1.f) - focus_tint) * p);
        }
        if (!ies.empty()) {
            const float x = theta / kPi * float(kIesSamples - 1);
            const int i = std::min(int(x), kIesSamples - 2);
            const float t = x - float(i);
            out = out * ((1.f - t) * ies[i] + t * ies[i + 1]);
        }
        return out;
    }
};

}  // namespace tessera
