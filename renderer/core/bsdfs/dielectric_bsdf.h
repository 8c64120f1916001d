// Smooth or rough (GGX, Walter et al. 2007) dielectric interface with exact Fresnel:
// reflection with probability F, transmission with 1 - F. eta = ior of the side below the
// normal (the outside is vacuum/air). eta == 1 is an invisible interface: a delta
// pass-through wi = -wo at any roughness (the generalized half vector is undefined).
// Sided, unlike the opaque kinds: wo.z > 0 is outside, wo.z < 0 inside.
#pragma once

#include <optional>

#include "bsdf_sample.h"
#include "math.h"
#include "microfacet.h"

namespace tessera {

class DielectricBSDF {
public:
    static constexpr const char* kName = "dielectric";

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

}  // namespace tessera
