// The dome (UsdLux DomeLight): constant radiance from every direction, or a lat-long
// texture (OpenEXR convention, +Y pole in the dome's own space) importance-sampled by
// luminance * sin(theta).
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include "distribution_2d.h"
#include "distant_light.h"
#include "light.h"

namespace tessera {

class DomeLight {
public:
    DomeLight() = default;
    // `radiance` scales the texture; without a texture (width 0) it is the radiance.
    // world_to_light is row-major (the dome's rotation, poleAxis included). Throws
    // std::invalid_argument for a bad texture.
    DomeLight(Color radiance, uint32_t width, uint32_t height, const std::vector<float>& rgb,
              const float world_to_light[9])
        : radiance_(radiance) {
        if (width == 0) return;
        if (rgb.size() != size_t(width) * height * 3 || height == 0)
            throw std::invalid_argument("dome texture size does not match its pixels");
        for (float v : rgb)
            if (!(v >= 0.f) || !std::isfinite(v)) throw std::invalid_argument("dome texture has negative or non-finite texels");
        w_ = width;
        h_ = height;
        rgb_ = rgb;
        std::copy(world_to_light, world_to_light + 9, m_);
        std::vector<float> weights(size_t(w_) * h_);
        for (uint32_t y = 0; y < h_; ++y) {
            const float sin_theta = std::sin(kPi * (float(y) + 0.5f) / float(h_));
            for (uint32_t x = 0; x < w_; ++x) {
                const float* t = &rgb_[3 * (size_t(y) * w_ + x)];
                weights[size_t(y) * w_ + x] = Luminance(Color(t[0], t[1], t[2])) * sin_theta;
            }
        }
        distribution_ = Distribution2D(weights, w_, h_);
    }

    Color radiance() const { return radiance_; }
    bool textured() const { return w_ > 0; }
    // Emits at all (a black texture has no sampling distribution and cannot be sampled).
    bool active() const { return !IsBlack(radiance_) && (!textured() || !distribution_.empty()); }

    // Solid-angle mean of the texture's luminance (1 without a texture), for the light's power.
    double MeanLuminance() const {
        if (!textured()) return 1.0;
        double sum = 0.0, weight = 0.0;
        for (uint32_t y = 0; y < h_; ++y) {
            double sin_theta = std::sin(kPi * (y + 0.5) / h_);
            for (uint32_t x = 0; x < w_; ++x) {
                const float* t = &rgb_[3 * (size_t(y) * w_ + x)];
                sum += Luminance(Color(t[0], t[1], t[2])) * sin_theta;
                weight += sin_theta;
            }
        }
        return sum / weight;
    }

    // Radiance from direction w (toward the dome) and the solid-angle density of Sample
    // having chosen it.
    Color Radiance(Vec3 w, float* pdf) const {
        if (!textured()) {
            *pdf = 1.f / (4.f * kPi);
            return radiance_;
        }
        const float* m = m_;
        Vec3 l(m[0] * w.x + m[1] * w.y + m[2] * w.z, m[3] * w.x + m[4] * w.y + m[5] * w.z,
               m[6] * w.x + m[7] * w.y + m[8] * w.z);
        // OpenEXR lat-long: longitude +pi..-pi across, latitude +pi/2..-pi/2 down; (lat 0,
        // lon 0) is +z and (0, pi/2) is +x.
        const float lat = std::asin(std::clamp(l.y, -1.f, 1.f)), lon = std::atan2(l.x, l.z);
        const Vec2 uv{0.5f - lon * kInv2Pi, 0.5f - lat * kInvPi};
        const float cos_lat = std::cos(lat);
        *pdf = cos_lat > 0.f ? distribution_.Pdf(uv) / (2.f * kPi * kPi * cos_lat) : 0.f;
        uint32_t x = std::min(w_ - 1, uint32_t(std::max(0.f, uv.x) * float(w_)));
        uint32_t y = std::min(h_ - 1, uint32_t(std::max(0.f, uv.y) * float(h_)));
        const float* t = &rgb_[3 * (size_t(y) * w_ + x)];
        return radiance_ * Color(t[0], t[1], t[2]);
    }

    // A direction toward the dome (returned), its solid-angle density and radiance.
    Vec3 Sample(Vec2 u, float* pdf, Color* L) const {
        if (!textured()) {
            float z = 1.f - 2.f * u.x, r = std::sqrt(std::max(0.f, 1.f - z * z)), phi = 2.f * kPi * u.y;
            *pdf = 1.f / (4.f * kPi);
            *L = radiance_;
            return Vec3(r * std::cos(phi), r * std::sin(phi), z);
        }
        float pdf_uv;
        const Vec2 uv = distribution_.Sample(u, &pdf_uv);
        const float lon = kPi * (1.f - 2.f * uv.x), lat = kPi * (0.5f - uv.y);
        const float cos_lat = std::cos(lat);
        const Vec3 l(cos_lat * std::sin(lon), std::sin(lat), cos_lat * std::cos(lon));
        const float* m = m_;  // world = M^T l (M is a rotation)
        const Vec3 w = Normalize(Vec3(m[0] * l.x + m[3] * l.y + m[6] * l.z, m[1] * l.x + m[4] * l.y + m[7] * l.z,
                                      m[2] * l.x + m[5] * l.y + m[8] * l.z));
        *pdf = cos_lat > 0.f ? pdf_uv / (2.f * kPi * kPi * cos_lat) : 0.f;
        // The radiance of the texel the direction falls in (as Radiance looks it up).
        float unused;
        *L = Radiance(w, &unused);
        return w;
    }

    // Next event estimation toward the dome.
    bool SampleLight(Vec2 u, LightSample* out) const {
        out->wi = Sample(u, &out->pdf, &out->radiance);
        out->distance = std::numeric_limits<float>::infinity();
        out->n = Vec3(0.f);
        return out->pdf > 0.f;
    }

    float PdfDirection(Vec3 w) const {
        float pdf;
        Radiance(-w, &pdf);
        return pdf;
    }

private:
    Color radiance_;
    uint32_t w_ = 0, h_ = 0;
    std::vector<float> rgb_;  // h_ rows of w_ RGB texels
    float m_[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    Distribution2D distribution_;  // proportional to luminance * sin(theta) over (u, v)
};

// The scene has one dome (index 0), an emitter when it is active.
template <>
struct EmitterOf<DomeLight> : InfiniteEmitterAnswers {
    static constexpr const char* kName = "dome";
    static constexpr bool kMoves = true;

    template <class S, class E>
    static bool Sample(const S& s, const E& e, Vec3, Vec2 u, LightSample* out) {
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        if (!s.lights_.template Of<DomeLight>()[e.index].SampleLight(u, out)) return false;
        out->wi = f.ToWorldDir(out->wi);
        return true;
    }
    template <class S, class E>
    static bool SampleEmission(const S& s, const E& e, Vec2 u_pos, Vec2 u_dir, float, EmissionSample* out) {
        float pdf_dir = 1.f;
        Color L;
        Vec3 wo = -s.lights_.template Of<DomeLight>()[e.index].Sample(u_dir, &pdf_dir, &L);  // light travels away
        if (!(pdf_dir > 0.f)) return false;
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        wo = f.ToWorldDir(wo);
        SampleInfiniteEmission(wo, pdf_dir, L, u_pos, s.scene_center_, s.scene_radius_, out);
        out->delta_light = false;
        return true;
    }
    template <class S, class E>
    static float PdfDirection(const S& s, const E& e, Vec3, Vec3 w) {
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        return s.lights_.template Of<DomeLight>()[e.index].PdfDirection(f.ToLightDir(w));
    }
    template <class E>
    static bool Delta(const E&) {
        return false;
    }
    template <class S, class E>
    static Color Environment(const S& s, const E& e, Vec3, Vec3 dir, float* pdf) {
        typename S::LightFrame f;
        s.FrameOf(e, &f);
        return s.lights_.template Of<DomeLight>()[e.index].Radiance(f.ToLightDir(dir), pdf);
    }
    template <class S, class Add>
    static void AddEmitters(const S& s, Add&& add) {
        const DomeLight& dome = s.lights_.template Of<DomeLight>()[0];
        if (!dome.active()) return;
        const double disk_area = kPi * double(s.scene_radius_) * s.scene_radius_;
        const double mean = dome.MeanLuminance();  // solid-angle mean of the texture's luminance
        add(0, 0.f, 0.f, 4.0 * kPi * disk_area * double(Luminance(dome.radiance())) * mean, true);
    }
};

}  // namespace tessera
