// The Lambertian BSDF, f = R / pi, two-sided, sampled by the cosine lobe.
#pragma once

#include <optional>

#include "bsdf_sample.h"
#include "math.h"

namespace tessera {

class DiffuseBSDF {
public:
    static constexpr const char* kName = "diffuse";

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

}  // namespace tessera
