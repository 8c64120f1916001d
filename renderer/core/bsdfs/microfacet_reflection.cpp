// MicrofacetReflection: wo and wi in the upper hemisphere throughout.
#include "microfacet_reflection.h"

#include <algorithm>
#include <cmath>

#include "fresnel.h"

namespace tessera {

namespace {
// Below this 1 - E1_avg (roughness under ~0.05) the compensation adds < 1e-4 and its
// normalisation would divide by almost nothing: it is left out (both f and the albedos).
constexpr float kMinMsLoss = 1e-4f;
}  // namespace

Color MicrofacetReflection::F(float cos_theta) const { return FrSchlick(f0, f90, cos_theta); }

Color MicrofacetReflection::f(Vec3 wo, Vec3 wi) const {
    if (!(wo.z > 0.f && wi.z > 0.f)) return Color(0.f);
    Vec3 wm = wo + wi;
    float len2 = LengthSquared(wm);
    if (len2 == 0.f) return Color(0.f);
    wm = wm / std::sqrt(len2);
    // D G F / (4 cosθo cosθi); the half angle is the same for wo and wi, so it is reciprocal.
    return F(Dot(wo, wm)) * (distrib.D(wm) * distrib.GOverCos(wo, wi) * 0.25f);
}

float MicrofacetReflection::PDF(Vec3 wo, Vec3 wi) const {
    if (!(wo.z > 0.f && wi.z > 0.f)) return 0.f;
    Vec3 wm = wo + wi;
    float len2 = LengthSquared(wm);
    if (len2 == 0.f) return 0.f;
    wm = wm / std::sqrt(len2);
    float cos_om = Dot(wo, wm);
    // dwm/dwi = 1 / (4 |wo·wm|) for mirror reflection.
    return cos_om > 0.f ? distrib.PDF(wo, wm) / (4.f * cos_om) : 0.f;
}

MicrofacetReflection::MicrofacetReflection(TrowbridgeReitz d, Color f0_, Color f90_)
    : distrib(d), f0(f0_), f90(f90_), row_(GGXRowOf(d.alpha())) {
    if (distrib.EffectivelySmooth()) return;
    const float e_avg = LookupGGXAverage(distrib.alpha()).e1;
    loss_avg_ = 1.f - e_avg;
    if (!(1.f - e_avg > kMinMsLoss)) return;
    const Color f_avg = f0 + (f90 - f0) * (1.f / 21.f);
    auto ch = [&](float fa) { return fa * fa * e_avg / (1.f - fa * (1.f - e_avg)); };
    fms_ = {ch(f_avg.x), ch(f_avg.y), ch(f_avg.z)};
}

Color MicrofacetReflection::SingleAlbedo(float mu) const {
    if (distrib.EffectivelySmooth()) return F(mu);
    return SingleAlbedo(mu, Table(mu));
}

Color MicrofacetReflection::SingleAlbedo(float mu, GGXAlbedo e) const {
    if (distrib.EffectivelySmooth()) return F(mu);
    return f0 * e.e1 + (f90 - f0) * e.e5;
}

Color MicrofacetReflection::MultiAlbedo(float mu) const {
    if (IsBlack(fms_)) return Color(0.f);
    return MultiAlbedo(Table(mu));
}

Color MicrofacetReflection::MultiAlbedo(GGXAlbedo e) const {
    if (IsBlack(fms_)) return Color(0.f);
    return fms_ * std::max(0.f, 1.f - e.e1);
}

Color MicrofacetReflection::AverageAlbedo() const {
    if (distrib.EffectivelySmooth()) return f0 + (f90 - f0) * (1.f / 21.f);
    GGXAlbedo a = LookupGGXAverage(distrib.alpha());
    return f0 * a.e1 + (f90 - f0) * a.e5 + fms_ * std::max(0.f, 1.f - a.e1);
}

Color MicrofacetReflection::fms(Vec3 wo, Vec3 wi) const {
    if (!(wo.z > 0.f && wi.z > 0.f) || IsBlack(fms_)) return Color(0.f);
    return fms(wo, wi, Table(wo.z), Table(wi.z));
}

Color MicrofacetReflection::fms(Vec3 wo, Vec3 wi, GGXAlbedo eo, GGXAlbedo ei) const {
    return fms(wo, wi, std::max(0.f, 1.f - eo.e1), std::max(0.f, 1.f - ei.e1));
}

Color MicrofacetReflection::fms(Vec3 wo, Vec3 wi, float loss_o, float loss_i) const {
    if (!(wo.z > 0.f && wi.z > 0.f) || IsBlack(fms_)) return Color(0.f);
    return fms_ * (loss_o * loss_i * kInvPi / loss_avg_);
}

bool MicrofacetReflection::Sample(Vec3 wo, Vec2 u, Vec3* wi) const {
    Vec3 wm = distrib.Sample_wm(wo, u);
    *wi = Reflect(wo, wm);
    // Visible normals can reflect below the horizon; that mass is lost (single scattering),
    // and PDF() integrates to the same value below 1, so the estimator stays consistent.
    return wi->z > 0.f;
}

}  // namespace tessera
