// UsdPreviewSurface with metallic = 1: F0 = F90 = colour (angle-independent), GGX with
// multiple-scattering compensation (MicrofacetReflection), two-sided. Sample_f picks the
// visible-normal lobe or, for the compensation term, the cosine lobe, in proportion to
// their albedos at wo.
#pragma once

#include <optional>

#include "bsdf_sample.h"
#include "math.h"
#include "microfacet_reflection.h"

namespace tessera {

class ConductorBSDF {
public:
    static constexpr const char* kName = "conductor";

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

}  // namespace tessera
