// BSDFs for UsdPreviewSurface, in the local shading frame (z = shading normal).
//
// Conventions (pbrt-v4's, so the book's integrators carry over):
//  * wo and wi are unit vectors pointing AWAY from the surface; wo is toward the camera
//    (TransportMode::Radiance) or toward the light (Importance).
//  * f(wo, wi) is the BSDF value WITHOUT the cosine; the integrator multiplies |wi.z|.
//  * PDF(wo, wi) is the solid-angle density of Sample_f producing wi, counting only the
//    non-delta lobes. f and PDF are 0 for any wi a delta lobe could produce.
//  * Sample_f returns, for a delta lobe, is_specular = true, pdf = the discrete probability
//    of having chosen that lobe, and f such that f |wi.z| / pdf is the sample's weight.
//    For a non-delta sample, f == f(wo, wi) and pdf == PDF(wo, wi) (the full mixture), so
//    MIS against light sampling works unchanged.
//  * Opaque BSDFs (Diffuse, Conductor, PreviewSurface's opaque lobes) are two-sided: wo
//    below the horizon is mirrored to the upper hemisphere, because USD meshes are often
//    single sheets. DielectricBSDF is sided: wo.z > 0 is outside (index 1), wo.z < 0 is
//    inside (index ior).
//  * wo exactly on the horizon (wo.z == 0) scatters nothing: f = 0, PDF = 0, no sample.
//
// TransportMode: Radiance BSDFs divide transmission by eta² (radiance is compressed into
// a smaller solid angle when entering a denser medium, Veach 1997 §5.2); Importance (light
// tracing, BDPT light subpaths) does not. f_Importance(wo, wi) == f_Radiance(wi, wo).
//
// No heap allocation: BSDF is a std::variant of small value types.
#pragma once

#include <cstdint>
#include <optional>
#include <variant>

#include "math.h"
#include "microfacet.h"

namespace tessera {

enum class TransportMode { Radiance, Importance };

enum BSDFFlags : uint32_t {
    kBSDFUnset = 0,
    kBSDFReflection = 1u << 0,
    kBSDFTransmission = 1u << 1,
    kBSDFDiffuse = 1u << 2,
    kBSDFGlossy = 1u << 3,
    kBSDFSpecular = 1u << 4,  // a delta lobe
};

struct BSDFSample {
    Color f;
    Vec3 wi;
    float pdf = 0.f;
    bool is_specular = false;      // sampled from a delta lobe
    bool is_transmission = false;  // wi on the other side of the surface from wo
    // Relative index of refraction n_wi_side / n_wo_side for transmission, 1 for reflection.
    // An integrator tracks the product of eta² over the path to keep Russian roulette from
    // reacting to the radiance scaling (pbrt-v4's etaScale).
    float eta = 1.f;
};

// f = R / pi.
class DiffuseBSDF {
public:
    explicit DiffuseBSDF(Color reflectance) : r_(reflectance) {}
    Color f(Vec3 wo, Vec3 wi) const;
    std::optional<BSDFSample> Sample_f(Vec3 wo, float uc, Vec2 u) const;
    float PDF(Vec3 wo, Vec3 wi) const;
    uint32_t Flags() const { return IsBlack(r_) ? kBSDFUnset : (kBSDFReflection | kBSDFDiffuse); }
    Color Albedo() const { return r_; }

private:
    Color r_;
};

// GGX reflection with Schlick Fresnel F(cos) = F0 + (F90 - F0)(1 - cos)^5 at the microfacet
// normal. Shared by ConductorBSDF and PreviewSurfaceBSDF's specular and clearcoat lobes.
// Works on the upper hemisphere only; callers mirror. Invariant: f(wo, wi) == f(wi, wo).
struct MicrofacetReflection {
    TrowbridgeReitz distrib;
    Color f0, f90;

    Color F(float cos_theta) const;
    Color f(Vec3 wo, Vec3 wi) const;                 // rough path only
    float PDF(Vec3 wo, Vec3 wi) const;               // rough path only
    bool Sample(Vec3 wo, Vec2 u, Vec3* wi) const;    // rough path only; false below horizon
};

// UsdPreviewSurface with metallic = 1: F0 = F90 = colour (angle-independent), GGX.
class ConductorBSDF {
public:
    ConductorBSDF(Color f0, Color f90, float alpha) : lobe_{TrowbridgeReitz(alpha), f0, f90} {}
    Color f(Vec3 wo, Vec3 wi) const;
    std::optional<BSDFSample> Sample_f(Vec3 wo, float uc, Vec2 u) const;
    float PDF(Vec3 wo, Vec3 wi) const;
    uint32_t Flags() const {
        return kBSDFReflection | (lobe_.distrib.EffectivelySmooth() ? kBSDFSpecular : kBSDFGlossy);
    }
    Color Albedo() const { return lobe_.f0; }

private:
    MicrofacetReflection lobe_;
};

// Smooth or rough (GGX, Walter et al. 2007) dielectric interface with exact Fresnel:
// reflection with probability F, transmission with 1 - F. eta = ior of the side below the
// normal (the outside is vacuum/air). eta == 1 is an invisible interface: a delta
// pass-through wi = -wo at any roughness (the generalized half vector is undefined).
class DielectricBSDF {
public:
    DielectricBSDF(float eta, float alpha, TransportMode mode) : eta_(eta), distrib_(alpha), mode_(mode) {}
    Color f(Vec3 wo, Vec3 wi) const;
    std::optional<BSDFSample> Sample_f(Vec3 wo, float uc, Vec2 u) const;
    float PDF(Vec3 wo, Vec3 wi) const;
    uint32_t Flags() const;
    Color Albedo() const { return Color(1.f); }
    float eta() const { return eta_; }
    bool IsSpecular() const { return eta_ == 1.f || distrib_.EffectivelySmooth(); }

private:
    float eta_;
    TrowbridgeReitz distrib_;
    TransportMode mode_;
};

// The UsdPreviewSurface inputs a path tracer honours, with the spec's defaults.
struct MaterialParams {
    Color diffuse_color = Color(0.18f);
    Color emissive_color = Color(0.f);  // not part of the BSDF: the integrator adds it
    bool use_specular_workflow = false;
    Color specular_color = Color(0.f);
    float metallic = 0.f;
    float roughness = 0.5f;
    float clearcoat = 0.f;
    float clearcoat_roughness = 0.01f;
    float opacity = 1.f;
    float opacity_threshold = 0.f;
    float ior = 1.5f;
};

// The UsdPreviewSurface mixture (see docs/materials.md for the derivation):
//
//   f = opacity · f_opaque + (1 - opacity) · f_dielectric(ior, roughness)
//   f_opaque(wo, wi) = c f_coat + Ac(wo) Ac(wi) [ f_spec + As(wo) As(wi) ρ / pi ]
//   Ac(w) = 1 - c Fc(|w.z|),  As(w) = 1 - Fs(|w.z|)   (per channel)
//
// where c = clearcoat, Fc = Schlick(0.04, 1), Fs = Schlick(F0, F90) of the workflow and
// ρ = diffuseColor (1 - metallic). Each attenuation appears once per direction, so f is
// reciprocal, and since a lobe's directional albedo is at most its Fresnel at the cosine,
// the reflected energy is at most 1 per channel (checked by the furnace tests).
class PreviewSurfaceBSDF {
public:
    PreviewSurfaceBSDF(const MaterialParams& p, TransportMode mode);
    Color f(Vec3 wo, Vec3 wi) const;
    std::optional<BSDFSample> Sample_f(Vec3 wo, float uc, Vec2 u) const;
    float PDF(Vec3 wo, Vec3 wi) const;
    uint32_t Flags() const;
    Color Albedo() const;

private:
    enum Lobe { kCoat, kSpec, kDiffuse, kGlass, kNumLobes };
    // Lobe selection probabilities at wo, proportional to each lobe's estimated reflectance.
    void LobeProbabilities(Vec3 wo, float p[kNumLobes]) const;
    Color OpaqueF(Vec3 wo, Vec3 wi) const;  // both mirrored to the upper hemisphere
    float LobePdf(int lobe, Vec3 wo, Vec3 wi) const;

    Color diffuse_;  // ρ = diffuseColor (1 - metallic)
    MicrofacetReflection spec_;
    MicrofacetReflection coat_;
    float clearcoat_;
    float opacity_;
    DielectricBSDF glass_;
    // LobeProbabilities depends on |wo.z| only, and one shading point asks for it with the
    // same wo up to three times (NEE's PDF, Sample_f and the PDF inside it): the last
    // answer is kept. A BSDF belongs to one thread's shading point, so this is not shared.
    mutable float cached_mu_ = -1.f;
    mutable float cached_p_[kNumLobes] = {};
};

// What the integrator holds per shading point.
class BSDF {
public:
    using Variant = std::variant<DiffuseBSDF, ConductorBSDF, DielectricBSDF, PreviewSurfaceBSDF>;
    BSDF() : v_(DiffuseBSDF(Color(0.f))) {}
    template <typename T>
    BSDF(const T& b) : v_(b) {}

    Color f(Vec3 wo, Vec3 wi) const {
        return std::visit([&](const auto& b) { return b.f(wo, wi); }, v_);
    }
    std::optional<BSDFSample> Sample_f(Vec3 wo, float uc, Vec2 u) const {
        return std::visit([&](const auto& b) { return b.Sample_f(wo, uc, u); }, v_);
    }
    float PDF(Vec3 wo, Vec3 wi) const {
        return std::visit([&](const auto& b) { return b.PDF(wo, wi); }, v_);
    }
    uint32_t Flags() const {
        return std::visit([](const auto& b) { return b.Flags(); }, v_);
    }
    // Some lobe is a delta: Sample_f may return is_specular samples.
    bool HasDelta() const { return Flags() & kBSDFSpecular; }
    // Some lobe is non-delta: light sampling (NEE) can contribute.
    bool IsNonSpecular() const { return Flags() & (kBSDFDiffuse | kBSDFGlossy); }
    bool IsGlossy() const { return Flags() & kBSDFGlossy; }
    bool HasTransmission() const { return Flags() & kBSDFTransmission; }
    // A bounded colour for the albedo AOV (denoisers): roughly the directional albedo.
    Color Albedo() const {
        return std::visit([](const auto& b) { return b.Albedo(); }, v_);
    }
    const Variant& variant() const { return v_; }

private:
    Variant v_;
};

// Builds the BSDF for a UsdPreviewSurface (sanitising out-of-range inputs). The glass rule,
// applied here and nowhere else: with opacity_threshold == 0, opacity blends the opaque
// surface with a dielectric interface of the same ior and roughness; opacity 0 is a pure
// DielectricBSDF (clear glass; with ior == 1, an invisible surface). With
// opacity_threshold > 0 the surface is a cutout (see IsCutout) and otherwise fully opaque.
BSDF MakePreviewSurfaceBSDF(const MaterialParams& p, TransportMode mode);

// Cutout mode (opacityThreshold > 0): a hit whose opacity (the material's, or a texture's
// at that point) is below the threshold is not a surface at all; the integrator continues
// the ray (and shadow rays) through it. Never true when opacity_threshold == 0.
inline bool IsCutout(const MaterialParams& p, float opacity) {
    return p.opacity_threshold > 0.f && opacity < p.opacity_threshold;
}

}  // namespace tessera
