// UsdPreviewSurface's full mixture (clearcoat, specular, albedo-scaled diffuse, partial
// opacity as a blend with glass), the kind the factory (bsdf.h) builds unless the inputs
// make it exactly one of the simpler kinds.
#pragma once

#include <optional>

#include "bsdf_sample.h"
#include "dielectric_bsdf.h"
#include "ggx_albedo.h"
#include "material_params.h"
#include "math.h"
#include "microfacet_reflection.h"

namespace tessera {

// What an untextured PreviewSurfaceBSDF computes from the angle to the normal alone,
// tabulated once per material (Scene does it) at the GGX tables' nodes in t = sqrt(mu)
// (ggx_albedo.h) and interpolated linearly in t as those tables are: the lobe selection
// probabilities, the diffuse scale 1 - Es per channel, the compensation's 1 - E1 and the
// coat's attenuation. The last three are linear in the tables' entries at a fixed
// roughness, so their interpolant is the tables' own up to rounding; the probabilities
// become an interpolant of the exact ones, used alike by Sample_f and PDF, so sampling
// stays exact in expectation. A vertex then pays a square root and a few lerps for what
// took four bilinear table lookups and the lobe arithmetic.
struct PreviewSurfaceTable {
    static constexpr int kNodes = ggx_table::kNumMu;
    static constexpr int kLobes = 4;
    float p[kNodes][kLobes];
    Color diffuse_scale[kNodes];
    float ms_loss[kNodes];     // max(0, 1 - E1) of the specular lobe
    float coat_atten[kNodes];  // 1 - c Ec
};

// The UsdPreviewSurface mixture (see docs/materials.md for the derivation):
//
//   f = opacity · f_opaque + (1 - opacity) · f_dielectric(ior, roughness)
//   f_opaque(wo, wi) = c f_coat + Ac(wo) Ac(wi) [ f_spec + ρ/pi (1 - Es(wo)) (1 - Es(wi)) / (1 - Es_avg) ]
//   Ac(w) = 1 - c Ec(|w.z|)                                             (per channel)
//
// where c = clearcoat, f_coat and f_spec are GGX lobes with Kulla-Conty compensation
// (MicrofacetReflection::f + fms), Es / Ec their directional albedos and Es_avg the
// cosine-weighted average of Es. The specular Fresnel is Schlick(F0, F90) with
// F90 = min(1, 50 max(F0)) for the dielectric part, so F0 = 0 (ior 1, or specularColor 0)
// has no specular at all; metallic lerps (F0, F90) to (diffuseColor, diffuseColor).
// ρ = diffuseColor (1 - metallic). The diffuse term is albedo-scaled: its albedo is
// exactly (1 - Es(wo)) ρ, so a white base reflects Es + (1 - Es) = 1 at every angle, and a
// base without specular is Lambert. The coat multiplies the base by its transmittance
// 1 - c Ec once per direction: reciprocal, and bounded by 1 per channel.
class PreviewSurfaceBSDF {
public:
    static constexpr const char* kName = "preview_surface";

    PreviewSurfaceBSDF(const MaterialParams& p, TransportMode mode);
    Color f(Vec3 wo, Vec3 wi) const;
    std::optional<BSDFSample> Sample_f(Vec3 wo, float uc, Vec2 u) const;
    float PDF(Vec3 wo, Vec3 wi) const;
    uint32_t Flags() const { return flags_; }
    Color Albedo() const;

    // The table of this BSDF's angle-only terms (computed directly, as without a table).
    PreviewSurfaceTable Tabulate() const;
    // Later calls read `table` (made by Tabulate of an equal BSDF; it must outlive this
    // BSDF and its copies); nullptr computes every term at each call again.
    void UseTable(const PreviewSurfaceTable* table) {
        table_ = table;
        cached_mu_ = -1.f;
    }

private:
    enum Lobe { kCoat, kSpec, kDiffuse, kGlass, kNumLobes };
    static_assert(int(kNumLobes) == PreviewSurfaceTable::kLobes);
    struct TableNode {
        int i;
        float ft;
    };
    static TableNode NodeOf(float mu);
    static float Interpolate(const float* v, TableNode n) { return v[n.i] + (v[n.i + 1] - v[n.i]) * n.ft; }
    static Color Interpolate(const Color* v, TableNode n) { return v[n.i] + (v[n.i + 1] - v[n.i]) * n.ft; }
    uint32_t ComputeFlags() const;
    // Lobe selection probabilities at wo, proportional to each lobe's estimated reflectance.
    void LobeProbabilities(Vec3 wo, float p[kNumLobes]) const;
    Color OpaqueF(Vec3 wo, Vec3 wi) const;  // both mirrored to the upper hemisphere
    Color OverCoat(Color base, Vec3 wo, Vec3 wi) const;  // the base seen through the clearcoat, plus the coat
    Color OverCoat(Color base, Vec3 wo, Vec3 wi, float atten_o, float atten_i) const;  // attenuations given
    float LobePdf(int lobe, Vec3 wo, Vec3 wi) const;

    float CoatAttenuation(float mu) const;  // Ac = 1 - c Ec(mu)
    Color DiffuseScale(float mu) const;     // 1 - Es(mu), clamped to [0, 1]
    Color DiffuseScale(float mu, GGXAlbedo e) const;  // e = spec_.Table(mu)

    Color diffuse_;  // ρ = diffuseColor (1 - metallic), divided by (1 - Es_avg) per channel
    Color diffuse_albedo_;  // ρ itself
    MicrofacetReflection spec_;
    MicrofacetReflection coat_;
    float clearcoat_;
    float opacity_;
    DielectricBSDF glass_;
    uint32_t flags_ = 0;
    // LobeProbabilities depends on |wo.z| only, and one shading point asks for it with the
    // same wo up to three times (NEE's PDF, Sample_f and the PDF inside it): the last
    // answer is kept. A BSDF belongs to one thread's shading point, so this is not shared.
    mutable float cached_mu_ = -1.f;
    mutable float cached_p_[kNumLobes] = {};
    const PreviewSurfaceTable* table_ = nullptr;
};

}  // namespace tessera
