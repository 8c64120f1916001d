// The BSDF an integrator holds per shading point: one value of any kind in bsdf_kinds.h
// (no heap allocation: a std::variant of small value types), and the factory that makes
// one from a UsdPreviewSurface. The conventions every kind follows are in bsdf_sample.h.
#pragma once

#include <cstdint>
#include <optional>
#include <type_traits>
#include <variant>

#include "bsdf_kinds.h"
#include "bsdf_sample.h"
#include "feature_set.h"
#include "material_params.h"
#include "math.h"

namespace tessera {

class BSDF {
public:
    using Variant = BuiltBSDFKinds::Variant;

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
    // The kind's name (its kName in bsdf_kinds.h).
    const char* KindName() const {
        return std::visit([](const auto& b) { return std::decay_t<decltype(b)>::kName; }, v_);
    }
    // The K held, or nullptr (also when this build cannot hold a K): e.g. Scene attaches
    // a PreviewSurfaceBSDF's table to it.
    template <typename K>
    K* GetIf() {
        static_assert(kIsBSDFKind<K>, "not a BSDF kind: add it to BSDFKinds");
        if constexpr (Holds<K>()) return std::get_if<K>(&v_);
        else return nullptr;
    }
    template <typename K>
    const K* GetIf() const {
        static_assert(kIsBSDFKind<K>, "not a BSDF kind: add it to BSDFKinds");
        if constexpr (Holds<K>()) return std::get_if<K>(&v_);
        else return nullptr;
    }

private:
    template <typename K>
    static constexpr bool Holds() {
        return bsdf_kinds_detail::IndexOf<K>(BuiltBSDFKinds{}) < BuiltBSDFKinds::kCount;
    }
    // The Lambert-only build's Scene refuses every material but a Lambertian, so the other
    // kinds are never made there; they still compile, as black.
    template <typename T>
    static Variant Hold(const T& b) {
        if constexpr (Holds<T>()) return b;
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

}  // namespace tessera
