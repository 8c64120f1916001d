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

}  // namespace tessera
