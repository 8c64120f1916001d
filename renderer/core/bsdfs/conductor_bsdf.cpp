#include "conductor_bsdf.h"

#include <algorithm>

#include "sampling.h"

namespace tessera {

float ConductorBSDF::MsProbability(float mu) const {
    if (lobe_.distrib.EffectivelySmooth() || IsBlack(lobe_.Fms())) return 0.f;
    // The same weights as PreviewSurfaceBSDF's specular and diffuse lobes with a black base,
    // so a pure-metal PreviewSurface samples exactly like this conductor.
    const float ws = std::max(kMinLobeWeight, Luminance(lobe_.SingleAlbedo(mu)));
    const float wm = std::max(kMinLobeWeight, Luminance(lobe_.MultiAlbedo(mu)));
    return wm / (ws + wm);
}

Color ConductorBSDF::f(Vec3 wo, Vec3 wi) const {
    if (lobe_.distrib.EffectivelySmooth() || !SameHemisphere(wo, wi)) return Color(0.f);
    if (wo.z < 0.f) wo = FlipZ(wo), wi = FlipZ(wi);
    return lobe_.f(wo, wi) + lobe_.fms(wo, wi);
}

float ConductorBSDF::PDF(Vec3 wo, Vec3 wi) const {
    if (lobe_.distrib.EffectivelySmooth() || !SameHemisphere(wo, wi)) return 0.f;
    if (wo.z < 0.f) wo = FlipZ(wo), wi = FlipZ(wi);
    const float pm = MsProbability(wo.z);
    return (1.f - pm) * lobe_.PDF(wo, wi) + pm * CosineHemispherePdf(wi.z);
}

std::optional<BSDFSample> ConductorBSDF::Sample_f(Vec3 wo, float uc, Vec2 u) const {
    if (wo.z == 0.f) return std::nullopt;
    bool flip = wo.z < 0.f;
    Vec3 w = flip ? FlipZ(wo) : wo;
    if (lobe_.distrib.EffectivelySmooth()) {
        Vec3 wi = MirrorAboutNormal(w);
        return BSDFSample{lobe_.F(w.z) / w.z, flip ? FlipZ(wi) : wi, 1.f, true, false, 1.f};
    }
    Vec3 wi;
    if (uc < MsProbability(w.z)) {
        wi = SampleCosineHemisphere(u);
    } else if (!lobe_.Sample(w, u, &wi)) {
        return std::nullopt;
    }
    float pdf = PDF(w, wi);
    if (!(pdf > 0.f)) return std::nullopt;
    return BSDFSample{f(w, wi), flip ? FlipZ(wi) : wi, pdf, false, false, 1.f};
}

}  // namespace tessera
