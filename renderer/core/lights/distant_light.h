// Light from a direction at infinity (UsdLux DistantLight): a cone of directions (the
// sun's disk), or with angle 0 a delta light.
#pragma once

#include <cmath>
#include <limits>

#include "light.h"
#include "sampling.h"

namespace tessera {

// `direction` is where the light travels (unit). With half_angle > 0 it is a cone of
// directions of constant `radiance`; with half_angle == 0 a delta light, and `radiance`
// holds the irradiance on a facing surface. `one_minus_cos` below is the cone's
// 1 - cos(half_angle), computed once by the scene (0: delta).
struct DistantLight {
    Vec3 direction;
    float half_angle = 0.f;
    Color radiance;

    bool Sample(Vec2 u, float one_minus_cos, LightSample* out) const {
        out->distance = std::numeric_limits<float>::infinity();
        out->radiance = radiance;
        out->n = Vec3(0.f);
        if (one_minus_cos == 0.f) {  // delta: the stored value is the irradiance
            out->wi = -direction;
            out->pdf = 1.f;
            out->is_delta = true;
            return true;
        }
        out->wi = Normalize(Frame::FromZ(-direction).FromLocal(SampleUniformCone(u, one_minus_cos)));
        out->pdf = 1.f / (2.f * kPi * one_minus_cos);
        return true;
    }

    // The direction light leaves in, its solid-angle density and radiance (the point on
    // the scene's bounding disk is the scene's: SampleInfiniteEmission).
    void SampleEmissionDirection(Vec2 u_dir, float one_minus_cos, Vec3* wo, float* pdf_dir, Color* L) const {
        *L = radiance;
        if (one_minus_cos > 0.f) {
            *wo = Normalize(Frame::FromZ(direction).FromLocal(SampleUniformCone(u_dir, one_minus_cos)));
            *pdf_dir = 1.f / (2.f * kPi * one_minus_cos);
        } else {
            *wo = direction;  // delta: L holds the irradiance
        }
    }

    // Radiance arriving along a ray leaving the scene in `dir`, and the solid-angle density
    // of Sample having chosen it (cones only: a delta direction is never met).
    Color Radiance(Vec3 dir, float one_minus_cos, float* pdf) const {
        // Inside the cone: 1 - cos(angle to the axis) <= 1 - cos(half angle).
        if (1.f - Dot(dir, -direction) <= one_minus_cos) {
            *pdf = 1.f / (2.f * kPi * one_minus_cos);
            return radiance;
        }
        *pdf = 0.f;
        return Color(0.f);
    }

    static float PdfDirection(float one_minus_cos) {
        return one_minus_cos > 0.f ? 1.f / (2.f * kPi * one_minus_cos) : 0.f;
    }
};

// A point on the disk of the scene's bounding sphere facing wo, upstream of the scene,
// for light at infinity leaving in wo (distant lights and the dome).
inline void SampleInfiniteEmission(Vec3 wo, float pdf_dir, Color L, Vec2 u_pos, Vec3 scene_center,
                                   float scene_radius, EmissionSample* out) {
    out->wo = wo;
    Vec2 disk = SampleUniformDiskConcentric(u_pos);
    Frame f = Frame::FromZ(out->wo);
    out->p = scene_center + (f.s * disk.x + f.t * disk.y - out->wo) * scene_radius;
    float pdf_pos = 1.f / (kPi * scene_radius * scene_radius);
    out->beta = L / (pdf_pos * pdf_dir);
    out->Le = L;
    out->pdf_pos = pdf_pos;
    out->pdf_dir = pdf_dir;
    out->infinite = true;
}

inline float InfiniteEmissionPdfPosition(float scene_radius) { return 1.f / (kPi * scene_radius * scene_radius); }

// What the kinds at infinity (distant lights, the dome) answer alike: their light leaves
// from the scene's bounding disk (SampleInfiniteEmission), and no light subpath vertex lies
// on them to connect toward. Their EmitterOf derives from it.
struct InfiniteEmitterAnswers {
    template <class S, class E>
    static bool EmissionToward(const S&, const E&, const EmissionSample&, Vec3, Color*, float*) {
        return false;
    }
    template <class S, class E>
    static float PdfPosition(const S& s, const E&) {
        return InfiniteEmissionPdfPosition(s.scene_radius_);
    }
    template <class E>
    static bool Infinite(const E&) {
        return true;
    }
};

// A distant light's emitter keeps its cone's 1 - cos(half angle) (0: a delta light).
template <>
struct EmitterOf<DistantLight> : InfiniteEmitterAnswers {
    static constexpr const char* kName = "distant";
    static constexpr bool kMoves = true;

    template <class S, class E>
    static bool Sample(const S& s, const E& e, Vec3, Vec2 u, LightSample* out) {
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        if (!s.lights_.template Of<DistantLight>()[e.index].Sample(u, e.one_minus_cos, out)) return false;
        out->wi = f.ToWorldDir(out->wi);
        return true;
    }
    template <class S, class E>
    static bool SampleEmission(const S& s, const E& e, Vec2 u_pos, Vec2 u_dir, float, EmissionSample* out) {
        float pdf_dir = 1.f;
        Color L;
        Vec3 wo;
        s.lights_.template Of<DistantLight>()[e.index].SampleEmissionDirection(u_dir, e.one_minus_cos, &wo, &pdf_dir,
                                                                              &L);
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        wo = f.ToWorldDir(wo);
        SampleInfiniteEmission(wo, pdf_dir, L, u_pos, s.scene_center_, s.scene_radius_, out);
        out->delta_light = e.one_minus_cos == 0.f;
        return true;
    }
    template <class S, class E>
    static float PdfDirection(const S&, const E& e, Vec3, Vec3) {
        return DistantLight::PdfDirection(e.one_minus_cos);
    }
    template <class E>
    static bool Delta(const E& e) {
        return e.one_minus_cos == 0.f;
    }
    template <class S, class E>
    static Color Environment(const S& s, const E& e, Vec3, Vec3 dir, float* pdf) {
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        return s.lights_.template Of<DistantLight>()[e.index].Radiance(f.ToLightDir(dir), e.one_minus_cos, pdf);
    }
    // A cone (not a delta light) is also seen by rays that escape: at_infinity.
    template <class S, class Add>
    static void AddEmitters(const S& s, Add&& add) {
        const auto& distants = s.lights_.template Of<DistantLight>();
        const double disk_area = kPi * double(s.scene_radius_) * s.scene_radius_;
        for (uint32_t i = 0; i < distants.size(); ++i) {
            const DistantLight& d = distants[i];
            if (IsBlack(d.radiance)) continue;
            float sin_half = std::sin(d.half_angle);
            float omc = d.half_angle > 0.f ? ConeOneMinusCos(sin_half * sin_half) : 0.f;
            // Irradiance on a facing surface: E = L pi sin^2 (cone), or the stored E (delta).
            double irradiance = double(Luminance(d.radiance)) * (omc > 0.f ? kPi * sin_half * sin_half : 1.0);
            add(i, 0.f, omc, irradiance * disk_area, omc > 0.f);
        }
    }
};

}  // namespace tessera
