// An emitting sphere (UsdLux SphereLight), an analytic Embree geometry of its own.
#pragma once

#include <algorithm>
#include <cmath>

#include "light.h"
#include "sampling.h"

namespace tessera {

struct SphereLight {
    Vec3 center;
    float radius = 0.f;
    Color radiance;

    // Uniform in the cone the sphere subtends (pbrt-v4 4.2 / 12.2.2): no samples wasted on
    // the hidden back side. From inside the sphere there is no light sampling.
    bool Sample(Vec3 ref, Vec2 u, LightSample* out) const {
        Vec3 to_center = center - ref;
        float d2 = LengthSquared(to_center);
        float r2 = radius * radius;
        if (d2 <= r2) return false;
        float d = std::sqrt(d2);
        float one_minus_cos = ConeOneMinusCos(r2 / d2);
        Vec3 local = SampleUniformCone(u, one_minus_cos);
        Vec3 wi = Normalize(Frame::FromZ(to_center / d).FromLocal(local));
        // Nearest intersection of ref + t wi with the sphere.
        float b = Dot(to_center, wi);
        float disc = std::max(0.f, r2 - (d2 - b * b));
        out->distance = b - std::sqrt(disc);
        out->wi = wi;
        out->radiance = radiance;
        out->pdf = 1.f / (2.f * kPi * one_minus_cos);
        out->p = ref + wi * out->distance;
        out->n = Normalize(out->p - center);
        // ref + t wi: the error of t (from b, d2 and r2) and of the product and sum.
        out->p_error = Gamma(8) * (MaxAbsComponent(ref) + std::abs(b) + d + radius) + Gamma(5) * MaxAbsComponent(center);
        return out->distance > 0.f;
    }

    // Solid-angle density at ref of Sample (the cone's).
    float Pdf(Vec3 ref) const {
        float d2 = LengthSquared(center - ref);
        float r2 = radius * radius;
        if (d2 <= r2) return 0.f;
        return 1.f / (2.f * kPi * ConeOneMinusCos(r2 / d2));
    }

    // Uniform point, cosine-weighted direction. `area` = 4 pi r^2.
    bool SampleEmission(Vec2 u_pos, Vec2 u_dir, float area, EmissionSample* out) const {
        float z = 1.f - 2.f * u_pos.x, r = std::sqrt(std::max(0.f, 1.f - z * z)), phi = 2.f * kPi * u_pos.y;
        Vec3 n(r * std::cos(phi), r * std::sin(phi), z);
        out->p = center + n * radius;
        out->p_error = Gamma(5) * (MaxAbsComponent(center) + radius);
        out->n = n;
        out->wo = Normalize(Frame::FromZ(n).FromLocal(SampleCosineHemisphere(u_dir)));
        out->beta = radiance * (kPi * area);
        out->on_surface = true;
        out->Le = radiance;
        out->pdf_pos = 1.f / area;
        out->pdf_dir = std::abs(Dot(out->wo, n)) * kInvPi;
        out->infinite = out->delta_light = false;
        return true;
    }

    static float PdfDirection(Vec3 n, Vec3 w) { return std::max(0.f, Dot(n, w)) * kInvPi; }
};

// The sphere is also scene geometry (hits on it are emitter hits: Scene::Emitted, EmitterPdf);
// SphereAt gives it at this thread's shutter time.
template <>
struct EmitterOf<SphereLight> : AreaEmitterAnswers {
    static constexpr const char* kName = "sphere";
    static constexpr bool kMoves = true;

    template <class S, class E>
    static bool Sample(const S& s, const E& e, Vec3 ref, Vec2 u, LightSample* out) {
        return s.SphereAt(e.index).Sample(ref, u, out);
    }
    template <class S, class E>
    static bool SampleEmission(const S& s, const E& e, Vec2 u_pos, Vec2 u_dir, float, EmissionSample* out) {
        if (!s.SphereAt(e.index).SampleEmission(u_pos, u_dir, e.area, out)) return false;
        out->Le_unshaped = out->Le;
        return true;
    }
    template <class S, class E>
    static float PdfDirection(const S&, const E&, Vec3 n, Vec3 w) {
        return SphereLight::PdfDirection(n, w);
    }
    template <class S, class E>
    static bool EmissionToward(const S&, const E&, const EmissionSample& es, Vec3 w, Color* Le_cos, float* pdf_dir) {
        const float c = Dot(es.n, w);
        *pdf_dir = SphereLight::PdfDirection(es.n, w);
        if (c > 0.f) *Le_cos = es.Le_unshaped * c;
        return true;
    }
    template <class S, class Add>
    static void AddEmitters(const S& s, Add&& add) {
        const auto& spheres = s.lights_.template Of<SphereLight>();
        for (uint32_t i = 0; i < spheres.size(); ++i) {
            if (IsBlack(spheres[i].radiance)) continue;
            float area = 4.f * kPi * spheres[i].radius * spheres[i].radius;
            add(i, area, 0.f, double(Luminance(spheres[i].radiance)) * area * kPi, false);
        }
    }
};

}  // namespace tessera
