// An emissive triangle (any mesh whose material emits; prototypes' triangles once per
// instance): an area light sampled uniformly by area.
#pragma once

#include <algorithm>
#include <cmath>

#include "light.h"
#include "sampling.h"

namespace tessera {

// One emissive triangle as the scene resolves it for a query: world-space corners, the
// sign that turns Cross(p1 - p0, p2 - p0) into the emitting normal, its world area and
// sidedness. `emission(b1, b2)` gives the emitted radiance at barycentrics (b1, b2)
// (textured emission), before sidedness.
struct TriangleLight {
    Vec3 p0, p1, p2;
    float orientation = 1.f;
    float area = 0.f;
    bool two_sided = false;
    bool instanced = false;  // placed by an instance: its corners carry the transform's rounding

    float InstanceError() const {
        return instanced ? Gamma(3) * std::max(MaxAbsComponent(p0), std::max(MaxAbsComponent(p1), MaxAbsComponent(p2)))
                         : 0.f;
    }

    template <typename Emission>
    bool Sample(Vec3 ref, Vec2 u, Emission&& emission, LightSample* out) const {
        Vec3 b = SampleUniformTriangle(u);
        float p_error;
        const Vec3 p = TrianglePoint(p0, p1, p2, b.y, b.z, &p_error);
        Vec3 ng = Normalize(Cross(p1 - p0, p2 - p0)) * orientation;
        Vec3 to_light = p - ref;
        float d2 = LengthSquared(to_light);
        if (!(d2 > 0.f)) return false;
        float d = std::sqrt(d2);
        Vec3 wi = to_light / d;
        float cos_light = Dot(ng, -wi);
        if (!two_sided && cos_light <= 0.f) return false;
        cos_light = std::abs(cos_light);
        if (cos_light < 1e-7f) return false;
        out->wi = wi;
        out->distance = d;
        out->radiance = emission(b.y, b.z);
        out->pdf = d2 / (cos_light * area);  // area measure 1/A converted to solid angle
        out->n = ng;
        out->p = p;
        out->p_error = p_error;
        if (instanced) out->p_error += InstanceError();
        return true;
    }

    // Uniform point, cosine-weighted direction (on a random side if two-sided).
    template <typename Emission>
    bool SampleEmission(Vec2 u_pos, Vec2 u_dir, float u_side, Emission&& emission, EmissionSample* out) const {
        Vec3 b = SampleUniformTriangle(u_pos);
        Vec3 n = Normalize(Cross(p1 - p0, p2 - p0)) * orientation;
        const Color Le = emission(b.y, b.z);
        float sides = 1.f;
        if (two_sided) {
            sides = 2.f;
            if (u_side < 0.5f) n = -n;
        }
        out->p = TrianglePoint(p0, p1, p2, b.y, b.z, &out->p_error);
        if (instanced) out->p_error += InstanceError();
        out->n = n;
        out->wo = Normalize(Frame::FromZ(n).FromLocal(SampleCosineHemisphere(u_dir)));
        // Le cos / ((1/A) (cos/pi) (1/sides)) = Le pi A sides
        out->beta = Le * (kPi * area * sides);
        out->on_surface = true;
        out->Le = Le;
        out->pdf_pos = 1.f / area;
        out->pdf_dir = std::abs(Dot(out->wo, n)) * kInvPi / sides;
        out->infinite = out->delta_light = false;
        return true;
    }
};

// Solid-angle density at ref of sampling, by area, the point `p` (geometric normal ng)
// of a triangle of area `area`.
inline float TriangleLightPdf(Vec3 ref, Vec3 p, Vec3 ng, float area) {
    Vec3 to_light = p - ref;
    float d2 = LengthSquared(to_light);
    float cos_light = std::abs(Dot(ng, to_light)) / std::sqrt(d2);
    if (cos_light < 1e-7f) return 0.f;
    return d2 / (cos_light * area);
}

inline float TriangleLightPdfDirection(bool two_sided, Vec3 n, Vec3 w) {
    if (two_sided) return std::abs(Dot(n, w)) * kInvPi * 0.5f;
    return std::max(0.f, Dot(n, w)) * kInvPi;
}

// Emissive triangles are scene geometry: the Scene makes their emitters from its meshes
// (BuildGeometryAndLights) and resolves one for a query (TriangleLightOf); their emission
// is the material's, textured and shaped.
template <>
struct EmitterOf<TriangleLight> : AreaEmitterAnswers {
    static constexpr const char* kName = "triangle";
    static constexpr bool kMoves = false;  // moves with its mesh or instance instead

    template <class S, class E>
    static bool Sample(const S& s, const E& e, Vec3 ref, Vec2 u, LightSample* out) {
        if (!s.TriangleLightOf(e).Sample(
                ref, u, [&](float b1, float b2) { return s.TriangleEmission(e.mesh, e.index, b1, b2); }, out))
            return false;
        const auto& m = s.MaterialOf(e.mesh, e.index);
        if (m.emission_shaping >= 0)  // toward ref, about the side it faces
            out->radiance =
                out->radiance * s.EmissionShaping(m, Dot(out->n, out->wi) <= 0.f ? out->n : -out->n, -out->wi);
        return true;
    }
    template <class S, class E>
    static bool SampleEmission(const S& s, const E& e, Vec2 u_pos, Vec2 u_dir, float u_side, EmissionSample* out) {
        if (!s.TriangleLightOf(e).SampleEmission(
                u_pos, u_dir, u_side,
                [&](float b1, float b2) { return s.TriangleEmission(e.mesh, e.index, b1, b2); }, out))
            return false;
        out->Le_unshaped = out->Le;
        const auto& m = s.MaterialOf(e.mesh, e.index);
        if (m.emission_shaping >= 0) {  // out->n is the side it leaves from
            const Color f = s.EmissionShaping(m, out->n, out->wo);
            out->beta = out->beta * f;
            out->Le = out->Le * f;
        }
        return true;
    }
    template <class S, class E>
    static float PdfDirection(const S& s, const E& e, Vec3 n, Vec3 w) {
        return TriangleLightPdfDirection(s.MaterialOf(e.mesh, e.index).two_sided_emission, n, w);
    }
    template <class S, class E>
    static bool EmissionToward(const S& s, const E& e, const EmissionSample& es, Vec3 w, Color* Le_cos,
                               float* pdf_dir) {
        const auto& m = s.MaterialOf(e.mesh, e.index);
        *pdf_dir = TriangleLightPdfDirection(m.two_sided_emission, es.n, w);
        const float c = Dot(es.n, w);
        if (!(c > 0.f) && !(m.two_sided_emission && c < 0.f)) return true;
        const Vec3 side = c > 0.f ? es.n : -es.n;
        const Color Le = m.emission_shaping < 0 ? es.Le_unshaped : es.Le_unshaped * s.EmissionShaping(m, side, w);
        *Le_cos = Le * std::abs(c);
        return true;
    }
    template <class S, class Add>
    static void AddEmitters(const S&, Add&&) {}  // made from the meshes, before every other kind
};

}  // namespace tessera
