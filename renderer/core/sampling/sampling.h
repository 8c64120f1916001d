// Warps from the unit square to the domains the integrator samples, with their pdfs,
// and the MIS heuristic. Each warp's pdf is checked numerically in core/sampling/sampling_test.cpp.
#pragma once

#include <cmath>

#include "math.h"

namespace tessera {

// Shirley-Chiu concentric map: uniform on the unit disk, low distortion.
inline Vec2 SampleUniformDiskConcentric(Vec2 u) {
    float ox = 2.f * u.x - 1.f, oy = 2.f * u.y - 1.f;
    if (ox == 0.f && oy == 0.f) return {0.f, 0.f};
    float r, theta;
    if (std::abs(ox) > std::abs(oy)) {
        r = ox;
        theta = (kPi / 4.f) * (oy / ox);
    } else {
        r = oy;
        theta = (kPi / 2.f) - (kPi / 4.f) * (ox / oy);
    }
    return {r * std::cos(theta), r * std::sin(theta)};
}

// Malley's method: pdf(w) = cos(theta) / pi over the hemisphere around +z.
inline Vec3 SampleCosineHemisphere(Vec2 u) {
    Vec2 d = SampleUniformDiskConcentric(u);
    float z = std::sqrt(std::max(0.f, 1.f - d.x * d.x - d.y * d.y));
    return {d.x, d.y, z};
}
inline float CosineHemispherePdf(float cos_theta) { return cos_theta > 0.f ? cos_theta * kInvPi : 0.f; }

// Uniform barycentrics (b0, b1, b2) on a triangle; pdf = 1 / area.
inline Vec3 SampleUniformTriangle(Vec2 u) {
    float su0 = std::sqrt(u.x);
    float b0 = 1.f - su0, b1 = u.y * su0;
    return {b0, b1, 1.f - b0 - b1};
}

// 1 - cos(theta_max) of the cone a sphere subtends, given sin^2(theta_max), computed
// without cancellation for small cones (a far-away small light).
inline float ConeOneMinusCos(float sin2_max) {
    return sin2_max < 1e-3f ? 0.5f * sin2_max * (1.f + 0.25f * sin2_max)
                            : 1.f - std::sqrt(std::max(0.f, 1.f - sin2_max));
}
// Uniform over the cone of directions around +z with 1 - cos(theta_max) = one_minus_cos;
// pdf = 1 / (2 pi one_minus_cos).
inline Vec3 SampleUniformCone(Vec2 u, float one_minus_cos) {
    float a = u.x * one_minus_cos;  // 1 - cos(theta)
    float cos_theta = 1.f - a;
    float sin_theta = std::sqrt(std::max(0.f, a * (2.f - a)));
    float phi = 2.f * kPi * u.y;
    return {sin_theta * std::cos(phi), sin_theta * std::sin(phi), cos_theta};
}

// Veach's power heuristic (beta = 2) for two strategies with one sample each.
inline float PowerHeuristic(float f_pdf, float g_pdf) {
    float f = f_pdf * f_pdf, g = g_pdf * g_pdf;
    if (std::isinf(f)) return 1.f;
    return f + g > 0.f ? f / (f + g) : 0.f;
}

// Russian roulette survives with probability min(1, max channel of beta x this scale). A
// camera path starts at beta = 1, but a light path starts at Le / pdf, in flux units
// (thousands for a small bright light): rouletting that absolute value never ends a light
// path until its throughput has fallen below 1, some ten bounces in a white room. The
// scale makes roulette see the throughput relative to the subpath's start; it is exactly 1
// for camera paths. Any survival probability keeps the estimator unbiased.
inline float RouletteScale(Color beta_start) {
    const float m = MaxComponent(beta_start);
    return m > 0.f && std::isfinite(m) ? 1.f / m : 1.f;
}

}  // namespace tessera
