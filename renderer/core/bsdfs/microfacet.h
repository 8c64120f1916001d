// GGX / Trowbridge-Reitz microfacet distribution with Smith masking and visible-normal
// sampling, in the local shading frame (z = macro normal). Math follows pbrt-v4 §9.6:
//
//   D(m)      = a² / (pi (cos²θm (a² - 1) + 1)²)                 for m.z > 0, else 0
//             = a² / (pi (a² cos²θm + sin²θm)²)
//   Λ(w)      = (sqrt(1 + a² tan²θ) - 1) / 2
//   G1(w)     = 1 / (1 + Λ(w))
//   G(wo, wi) = 1 / (1 + Λ(wo) + Λ(wi))        height-correlated Smith (not separable)
//   D_w(m)    = G1(w) max(0, w·m) D(m) / |cos θw|    density of visible normals (Heitz 2014)
//
// Invariants: ∫ D(m) cosθm dm = 1, and ∫ D_w(m) dm = 1 for every w with w.z != 0.
// G1 and G are written in forms with no tangent, so w on the horizon gives 0, not NaN.
#pragma once

#include <algorithm>
#include <cmath>

#include "math.h"

namespace tessera {

// Direction helpers for the local frame (z = normal).
inline float AbsCosTheta(Vec3 w) { return std::abs(w.z); }
inline bool SameHemisphere(Vec3 a, Vec3 b) { return a.z * b.z > 0.f; }
inline Vec3 Reflect(Vec3 wo, Vec3 n) { return -wo + n * (2.f * Dot(wo, n)); }

// Refracts wi (pointing away from the surface, on the side n points to, Dot(wi, n) > 0)
// through an interface where eta = n_transmitted / n_incident. False on total internal
// reflection. The result points away from the surface on the other side.
inline bool Refract(Vec3 wi, Vec3 n, float eta, Vec3* wt) {
    float cos_i = Dot(n, wi);
    float sin2_i = std::max(0.f, 1.f - cos_i * cos_i);
    float sin2_t = sin2_i / (eta * eta);
    if (sin2_t >= 1.f) return false;
    float cos_t = std::sqrt(1.f - sin2_t);
    *wt = -wi / eta + n * (cos_i / eta - cos_t);
    return true;
}

class TrowbridgeReitz {
public:
    // Below this alpha the lobe is narrower than float directions can resolve usefully
    // (pbrt-v4 uses the same bound): BSDFs switch to their exact delta lobes instead.
    static constexpr float kMinAlpha = 1e-3f;

    // UsdPreviewSurface roughness is perceptual: alpha = roughness².
    static float RoughnessToAlpha(float roughness) {
        float r = std::isfinite(roughness) ? std::clamp(roughness, 0.f, 1.f) : 0.f;
        return r * r;
    }

    explicit TrowbridgeReitz(float alpha)
        : smooth_(!(alpha >= kMinAlpha)), alpha_(std::clamp(std::isfinite(alpha) ? alpha : 0.f, kMinAlpha, 1.f)) {}

    bool EffectivelySmooth() const { return smooth_; }
    float alpha() const { return alpha_; }

    float D(Vec3 m) const {
        if (m.z <= 0.f) return 0.f;
        // cos²θ (a² - 1) + 1 written as a² cos²θ + sin²θ, with sin²θ from x and y: near the
        // peak of a narrow lobe the first form cancels catastrophically in float (alpha
        // 0.0025 lost 2% of D there).
        float a2 = alpha_ * alpha_;
        float t = a2 * m.z * m.z + (m.x * m.x + m.y * m.y);
        return t > 0.f ? a2 / (kPi * t * t) : 0.f;
    }

    // sqrt(a² sin²θ + cos²θ) = |cosθ| sqrt(1 + a² tan²θ), the quantity Λ and G1 share.
    float Root(Vec3 w) const {
        float s2 = w.x * w.x + w.y * w.y;  // not 1 - cos², for the same reason as in D
        return std::sqrt(alpha_ * alpha_ * s2 + w.z * w.z);
    }
    float G1(Vec3 w) const {
        float c = std::abs(w.z);
        float denom = c + Root(w);
        return denom > 0.f ? 2.f * c / denom : 0.f;
    }
    float G(Vec3 wo, Vec3 wi) const {
        // 1 / (1 + Λo + Λi) multiplied through by 2|co||ci|.
        float co = std::abs(wo.z), ci = std::abs(wi.z);
        float denom = ci * Root(wo) + co * Root(wi);
        return denom > 0.f ? 2.f * co * ci / denom : 0.f;
    }

    // G(wo, wi) / (|cos θo| |cos θi|): the combination BSDFs need, finite down to grazing.
    float GOverCos(Vec3 wo, Vec3 wi) const {
        float denom = std::abs(wi.z) * Root(wo) + std::abs(wo.z) * Root(wi);
        return denom > 0.f ? 2.f / denom : 0.f;
    }

    // Density of visible normals seen from w, per unit solid angle of m.
    float PDF(Vec3 w, Vec3 m) const {
        float c = std::abs(w.z);
        if (c == 0.f) return 0.f;
        // Mirror w into the upper hemisphere: visible normals are those facing it.
        Vec3 wu = w.z < 0.f ? -w : w;
        return 2.f / (c + Root(w)) * D(m) * std::max(0.f, Dot(wu, m));  // G1(w) / c = 2 / (c + Root)
    }

    // Heitz 2018, "Sampling the GGX Distribution of Visible Normals": stretch w to the
    // alpha = 1 configuration, sample the projected hemisphere (a disk whose far half is
    // squashed by the hemisphere's tilt), unstretch. Returns m with m.z > 0 and
    // Dot(w, m) >= 0 for w mirrored into the upper hemisphere.
    Vec3 Sample_wm(Vec3 w, Vec2 u) const {
        Vec3 wu = w.z < 0.f ? -w : w;  // the same mirroring as PDF
        Vec3 wh = Normalize(Vec3(alpha_ * wu.x, alpha_ * wu.y, wu.z));
        Vec3 t1 = wh.z < 0.99999f ? Normalize(Cross(Vec3(0.f, 0.f, 1.f), wh)) : Vec3(1.f, 0.f, 0.f);
        Vec3 t2 = Cross(wh, t1);
        float r = std::sqrt(u.x), phi = 2.f * kPi * u.y;
        float p1 = r * std::cos(phi), p2 = r * std::sin(phi);
        float s = 0.5f * (1.f + wh.z);
        p2 = (1.f - s) * std::sqrt(std::max(0.f, 1.f - p1 * p1)) + s * p2;
        float p3 = std::sqrt(std::max(0.f, 1.f - p1 * p1 - p2 * p2));
        Vec3 nh = t1 * p1 + t2 * p2 + wh * p3;
        return Normalize(Vec3(alpha_ * nh.x, alpha_ * nh.y, std::max(1e-6f, nh.z)));
    }

private:
    bool smooth_;
    float alpha_;
};

}  // namespace tessera
