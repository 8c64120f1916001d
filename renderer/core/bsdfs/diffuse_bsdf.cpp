#include "diffuse_bsdf.h"

#include <cmath>

#include "microfacet.h"
#include "sampling.h"

namespace tessera {

Color DiffuseBSDF::f(Vec3 wo, Vec3 wi) const {
    return SameHemisphere(wo, wi) ? r_ * kInvPi : Color(0.f);
}

std::optional<BSDFSample> DiffuseBSDF::Sample_f(Vec3 wo, float, Vec2 u) const {
    if (wo.z == 0.f || IsBlack(r_)) return std::nullopt;
    Vec3 wi = SampleCosineHemisphere(u);
    if (wo.z < 0.f) wi.z = -wi.z;
    float pdf = CosineHemispherePdf(std::abs(wi.z));
    if (!(pdf > 0.f)) return std::nullopt;
    return BSDFSample{r_ * kInvPi, wi, pdf, false, false, 1.f};
}

float DiffuseBSDF::PDF(Vec3 wo, Vec3 wi) const {
    return SameHemisphere(wo, wi) && !IsBlack(r_) ? CosineHemispherePdf(std::abs(wi.z)) : 0.f;
}

}  // namespace tessera
