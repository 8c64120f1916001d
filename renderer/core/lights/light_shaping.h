// UsdLux ShapingAPI for point lights and one-sided area lights (about their emitting
// normal): a cone with a soft edge, focus, and an IES profile over the angle off the axis
// and the horizontal angle about it (IES type C: 0 along the light's +X, 90 along +Y).
// A factor on the light's intensity per emission direction; the light is still sampled
// uniformly (the factor changes what a direction carries, never which directions exist).
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "math.h"

namespace tessera {

// IES table: kIesSamples vertical angles 0..180 degrees (1 degree apart) by kIesAzimuths
// horizontal angles 0..360 (5 degrees apart, the last repeating the first), row-major by
// vertical angle.
constexpr int kIesSamples = 181;
constexpr int kIesAzimuths = 73;

struct LightShaping {
    bool enabled = false;
    // An area light's emission is shaped about its emitting normal, or (a cylinder, whose
    // normals turn around it) about the fixed axis.
    bool about_axis = false;
    Vec3 axis{0.f, 0.f, -1.f};  // unit emission axis in world space (the light's -Z)
    float cutoff = kPi;         // cone half angle, radians: nothing beyond it
    float smooth_start = kPi;   // angle where the soft edge starts to fall off
    float focus = 0.f;          // exponent on |cos| off the axis (0: none)
    Color focus_tint{0.f};      // what the focus falloff fades to
    Vec3 azimuth_zero{1.f, 0.f, 0.f};  // the light's +X in world space: horizontal angle 0
    std::vector<float> ies;     // kIesSamples x kIesAzimuths factors, or empty

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
        if (!ies.empty()) out = out * Ies(about, w, theta);
        return out;
    }

    // The IES factor, bilinear in the vertical angle theta and the horizontal angle phi of w
    // about `about`: 0 along azimuth_zero's part across the axis, 90 degrees along
    // zero x about (the light's +Y when about is its -Z, as type C photometry turns).
    float Ies(Vec3 about, Vec3 w, float theta) const {
        const float x = theta / kPi * float(kIesSamples - 1);
        const int i = std::min(int(x), kIesSamples - 2);
        const float t = x - float(i);
        float phi = 0.f;
        const Vec3 u = azimuth_zero - about * Dot(azimuth_zero, about);
        const float ul = Length(u);
        if (ul > 1e-6f) {
            const Vec3 ex = u / ul, ey = Cross(ex, about);
            phi = std::atan2(Dot(w, ey), Dot(w, ex));
            if (phi < 0.f) phi += 2.f * kPi;
        }
        const float y = phi / (2.f * kPi) * float(kIesAzimuths - 1);
        const int j = std::min(int(y), kIesAzimuths - 2);
        const float s = y - float(j);
        const float* row0 = &ies[size_t(i) * kIesAzimuths];
        const float* row1 = row0 + kIesAzimuths;
        const float a = (1.f - s) * row0[j] + s * row0[j + 1];
        const float b = (1.f - s) * row1[j] + s * row1[j + 1];
        return (1.f - t) * a + t * b;
    }
};

}  // namespace tessera
