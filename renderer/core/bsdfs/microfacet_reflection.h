// GGX reflection with Schlick Fresnel F(cos) = F0 + (F90 - F0)(1 - cos)^5 at the microfacet
// normal: the lobe ConductorBSDF and PreviewSurfaceBSDF's specular and clearcoat are made
// of (not a BSDF kind itself). Works on the upper hemisphere only; callers mirror.
// Invariant: f(wo, wi) == f(wi, wo).
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
#pragma once

#include "ggx_albedo.h"
#include "math.h"
#include "microfacet.h"

namespace tessera {

// Every lobe that can contribute keeps at least this selection weight, so a lobe whose
// albedo estimate at wo is 0 (F0 = 0 at normal incidence) is still sampled and BSDF
// sampling alone stays unbiased. Shared by the kinds that choose among these lobes, so a
// pure-metal PreviewSurface samples exactly like a ConductorBSDF.
inline constexpr float kMinLobeWeight = 0.02f;

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

}  // namespace tessera
