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
#include <type_traits>
#include <variant>

#include "feature_set.h"
#include "math.h"
#include "ggx_albedo.h"
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
    bool IsNonSpecular() const { return !IsBlack(r_); }  // as BSDF's, for kernels that shade with it directly
    Color Albedo() const { return r_; }

private:
    Color r_;
};

// GGX reflection with Schlick Fresnel F(cos) = F0 + (F90 - F0)(1 - cos)^5 at the microfacet
// normal. Shared by ConductorBSDF and PreviewSurfaceBSDF's specular and clearcoat lobes.
// Works on the upper hemisphere only; callers mirror. Invariant: f(wo, wi) == f(wi, wo).
//
// Energy compensation (Kulla & Conty 2017): single-scattering GGX loses the light that
// would scatter between microfacets (a white metal at roughness 1 reflects 0.31 head-on).
// fms adds it back as a reciprocal, cosine-like lobe
//   fms(wo, wi) = Fms (1 - E1(wo)) (1 - E1(wi)) / (pi (1 - E1_avg)),
//   Fms = F_avg² E1_avg / (1 - F_avg (1 - E1_avg)),  F_avg = F0 + (F90 - F0) / 21,
// whose albedo is Fms (1 - E1(wo)): with F = 1 the lobe reflects exactly 1 at every angle.
// E1, E5 and their averages come from ggx_albedo.h. A smooth lobe is a delta with albedo
// F(cos) and no multiple scattering.
// Everything that depends on the roughness and Fresnel only (the tables' roughness row,
// Fms, 1 - E1_avg) is computed once by the constructor: a shading point asks for the
// albedos up to a dozen times.
class MicrofacetReflection {
public:
    MicrofacetReflection(TrowbridgeReitz d, Color f0_, Color f90_);

    TrowbridgeReitz distrib;
    Color f0, f90;

    Color F(float cos_theta) const;
    Color f(Vec3 wo, Vec3 wi) const;                 // rough path only, single scattering
    Color fms(Vec3 wo, Vec3 wi) const;               // rough path only, multiple scattering
    float PDF(Vec3 wo, Vec3 wi) const;               // rough path only, single-scattering lobe
    bool Sample(Vec3 wo, Vec2 u, Vec3* wi) const;    // rough path only; false below horizon

    // The tabulated E1, E5 at mu = cos θ in [0, 1] (rough lobes only): the forms below that
    // take it let a caller that needs several albedos at one angle look it up once.
    GGXAlbedo Table(float mu) const { return LookupGGXAlbedo(mu, row_); }

    // Directional albedos at mu = cos θ in [0, 1] (per channel) and the cosine-weighted
    // hemispherical average of the total, 2 ∫ Albedo(mu) mu dmu.
    Color SingleAlbedo(float mu) const;
    Color SingleAlbedo(float mu, GGXAlbedo e) const;
    Color MultiAlbedo(float mu) const;
    Color MultiAlbedo(GGXAlbedo e) const;
    Color Albedo(float mu) const { return SingleAlbedo(mu) + MultiAlbedo(mu); }
    Color AverageAlbedo() const;
    Color Fms() const { return fms_; }  // 0 when smooth or when E1_avg is so close to 1 that there is nothing to add
    Color fms(Vec3 wo, Vec3 wi, GGXAlbedo eo, GGXAlbedo ei) const;  // eo = Table(wo.z), ei = Table(wi.z)
    // The same from the losses max(0, 1 - E1) at wo and wi.
    Color fms(Vec3 wo, Vec3 wi, float loss_o, float loss_i) const;

private:
    GGXRoughnessRow row_;
    float loss_avg_ = 0.f;  // 1 - E1_avg
    Color fms_ = Color(0.f);
};

// UsdPreviewSurface with metallic = 1: F0 = F90 = colour (angle-independent), GGX with
// multiple-scattering compensation. Sample_f picks the visible-normal lobe or, for the
// compensation term, the cosine lobe, in proportion to their albedos at wo.
class ConductorBSDF {
public:
    ConductorBSDF(Color f0, Color f90, float alpha) : lobe_{TrowbridgeReitz(alpha), f0, f90} {}
    Color f(Vec3 wo, Vec3 wi) const;
    std::optional<BSDFSample> Sample_f(Vec3 wo, float uc, Vec2 u) const;
    float PDF(Vec3 wo, Vec3 wi) const;
    uint32_t Flags() const {
        return kBSDFReflection | (lobe_.distrib.EffectivelySmooth() ? kBSDFSpecular : kBSDFGlossy);
    }
    Color Albedo() const { return lobe_.Albedo(1.f); }

private:
    float MsProbability(float mu) const;  // probability of the cosine lobe at |wo.z| = mu
    MicrofacetReflection lobe_;
};

// Smooth or rough (GGX, Walter et al. 2007) dielectric interface with exact Fresnel:
// reflection with probability F, transmission with 1 - F. eta = ior of the side below the
// normal (the outside is vacuum/air). eta == 1 is an invisible interface: a delta
// pass-through wi = -wo at any roughness (the generalized half vector is undefined).
class DielectricBSDF {
public:
    // `tint` multiplies every transmission through the interface (MaterialX's
    // transmission_color at transmission_depth 0: coloured glass without an interior).
    DielectricBSDF(float eta, float alpha, TransportMode mode, Color tint = Color(1.f))
        : eta_(eta), distrib_(alpha), mode_(mode), tint_(tint) {}
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
    Color tint_;
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
    // Multiplies transmission through a fully transmissive surface (opacity 0): the colour
    // of MaterialX transmission at depth 0, applied at each crossing. 1: clear.
    Color transmission_tint = Color(1.f);
};

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

// What the integrator holds per shading point.
class BSDF {
public:
#ifdef TESSERA_LAMBERT_ONLY
    using Variant = std::variant<DiffuseBSDF>;
#else
    using Variant = std::variant<DiffuseBSDF, ConductorBSDF, DielectricBSDF, PreviewSurfaceBSDF>;
#endif
    BSDF() : v_(DiffuseBSDF(Color(0.f))) {}
    template <typename T>
    BSDF(const T& b) : v_(Hold(b)) {}

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
    // The PreviewSurfaceBSDF held, or nullptr (Scene attaches its table to it).
    PreviewSurfaceBSDF* preview_surface() {
#ifdef TESSERA_LAMBERT_ONLY
        return nullptr;
#else
        return std::get_if<PreviewSurfaceBSDF>(&v_);
#endif
    }

private:
    // The Lambert-only build's Scene refuses every material but a Lambertian, so the other
    // kinds are never made there; they still compile, as black.
    template <typename T>
    static Variant Hold(const T& b) {
        if constexpr (kFullFeatures || std::is_same_v<T, DiffuseBSDF>) return b;
        else return DiffuseBSDF(Color(0.f));
    }
    Variant v_;
};

// Builds the BSDF for a UsdPreviewSurface (sanitising out-of-range inputs). The glass rule,
// applied here and nowhere else: with opacity_threshold == 0, opacity blends the opaque
// surface with a dielectric interface of the same ior and roughness; opacity 0 is a pure
// DielectricBSDF (clear glass; with ior == 1, an invisible surface). With
// opacity_threshold > 0 the surface is a cutout (see IsCutout) and otherwise fully opaque.
BSDF MakePreviewSurfaceBSDF(const MaterialParams& p, TransportMode mode);

// The reflectance of a Lambertian equal to this UsdPreviewSurface, when there is one: an
// opaque surface without clearcoat whose specular Fresnel is 0 at every angle (F0 = F90 = 0:
// specularColor 0 in the specular workflow, or ior 1 and metallic 0), as exporters write a
// plain diffuse material. Then PreviewSurfaceBSDF's specular lobe and its multiple
// scattering vanish, the diffuse scale 1 - Es is exactly 1, and f = ρ/π with cosine
// sampling: the same values, bit for bit, at a fraction of the cost (and the scene keeps
// the Lambertian kernel). Untextured inputs only: the caller checks the texture slots.
std::optional<Color> ExactLambertianAlbedo(const MaterialParams& p);

// Cutout mode (opacityThreshold > 0): a hit whose opacity (the material's, or a texture's
// at that point) is below the threshold is not a surface at all; the integrator continues
// the ray (and shadow rays) through it. Never true when opacity_threshold == 0.
inline bool IsCutout(const MaterialParams& p, float opacity) {
    return p.opacity_threshold > 0.f && opacity < p.opacity_threshold;
}

// Presence mode (opacity_threshold < 0, which USD cannot mean: the translator's mark for a
// partial opacity that asks for no refraction): opacity is the probability that a hit is a
// surface at all, and the BSDF of the hits that are is opaque. The other hits pass
// straight through, camera and shadow rays alike (Scene::IsCutoutHit decides each one).
inline bool IsPresenceMode(const MaterialParams& p) { return p.opacity_threshold < 0.f; }

}  // namespace tessera
