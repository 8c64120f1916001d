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

template <>
struct EmitterOf<PointLight> {
    static constexpr const char* kName = "point";
    static constexpr bool kMoves = true;

    // Sampled as the light stands in its description, then moved to where it is now.
    template <class S, class E>
    static bool Sample(const S& s, const E& e, Vec3 ref, Vec2, LightSample* out) {
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        if (!s.lights_.template Of<PointLight>()[e.index].Sample(f.ToLightPoint(ref), out)) return false;
        if (f.m) {
            out->p = f.ToWorldPoint(out->p);
            out->wi = f.ToWorldDir(out->wi);
        }
        return true;
    }
    template <class S, class E>
    static bool SampleEmission(const S& s, const E& e, Vec2, Vec2 u_dir, float, EmissionSample* out) {
        if (!s.lights_.template Of<PointLight>()[e.index].SampleEmission(u_dir, out)) return false;
        typename S::LightFrame f;
        if (s.FrameOf(e, &f)) {
            out->p = f.ToWorldPoint(out->p);
            out->wo = f.ToWorldDir(out->wo);
        }
        return true;
    }
    template <class S, class E>
    static float PdfDirection(const S&, const E&, Vec3, Vec3) {
        return PointLight::PdfDirection();
    }
    template <class S, class E>
    static bool EmissionToward(const S& s, const E& e, const EmissionSample&, Vec3 w, Color* Le_cos, float* pdf_dir) {
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        const PointLight& light = s.lights_.template Of<PointLight>()[e.index];
        *pdf_dir = PointLight::PdfDirection();
        *Le_cos = light.intensity * light.shaping.Factor(f.ToLightDir(w));
        return true;
    }
    template <class S, class E>
    static float PdfPosition(const S&, const E&) {
        return PointLight::PdfPosition();
    }
    template <class E>
    static bool Infinite(const E&) {
        return false;
    }
    template <class E>
    static bool Delta(const E&) {
        return true;
    }
    template <class S, class E>
    static Color Environment(const S&, const E&, Vec3, Vec3, float*) {
        return Color(0.f);
    }
    // add(index, area, one_minus_cos, power, at_infinity) per light that emits.
    template <class S, class Add>
    static void AddEmitters(const S& s, Add&& add) {
        const auto& points = s.lights_.template Of<PointLight>();
        for (uint32_t i = 0; i < points.size(); ++i) {
            if (IsBlack(points[i].intensity)) continue;
            add(i, 0.f, 0.f, 4.0 * kPi * double(Luminance(points[i].intensity)), false);
        }
    }
};

}  // namespace tessera
