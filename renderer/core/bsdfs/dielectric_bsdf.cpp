// DielectricBSDF. Internally wo is brought to the upper hemisphere by mirroring z and the
// relative index e = n_below / n_above is inverted if wo started inside; every formula
// below then has the incident medium above with index 1 and the other below with index e.
#include "dielectric_bsdf.h"

#include <cmath>

#include "fresnel.h"

namespace tessera {

uint32_t DielectricBSDF::Flags() const {
    if (eta_ == 1.f) return kBSDFTransmission | kBSDFSpecular;
    return kBSDFReflection | kBSDFTransmission | (distrib_.EffectivelySmooth() ? kBSDFSpecular : kBSDFGlossy);
}

namespace {

struct RoughDielectricEval {
    Color f;
    float pdf = 0.f;
};

// Value and pdf of the rough interface for (wo, wi) with wo.z > 0, relative index e.
// Walter et al. 2007 eqs. 20-21 with the generalized half vector wm ∝ e wi + wo (pbrt-v4
// §9.7.5): reflection  D G F / (4 |cosθo cosθi|),
//          transmission D G (1 - F) |wi·wm| |wo·wm| / (|cosθo cosθi| (wi·wm + wo·wm / e)²),
// the latter divided by e² for radiance. The pdf is D_wo(wm) times the Jacobian dwm/dwi
// times the probability (F or 1 - F) of choosing that lobe.
RoughDielectricEval EvalRoughDielectric(const TrowbridgeReitz& d, float e, TransportMode mode, Vec3 wo, Vec3 wi) {
    RoughDielectricEval r{Color(0.f), 0.f};
    if (!(wo.z > 0.f) || wi.z == 0.f) return r;
    bool reflect = wi.z > 0.f;
    float etap = reflect ? 1.f : e;
    Vec3 wm = wi * etap + wo;
    float len2 = LengthSquared(wm);
    if (!(len2 > 0.f)) return r;
    wm = wm / std::sqrt(len2);
    if (wm.z < 0.f) wm = -wm;
    // Microfacets seen from behind by either direction contribute nothing.
    float cos_om = Dot(wo, wm), cos_im = Dot(wi, wm);
    if (cos_om <= 0.f || cos_im * wi.z <= 0.f) return r;
    float F = FrDielectric(cos_om, e);
    float Dm = d.D(wm);
    if (reflect) {
        r.f = Color(Dm * d.GOverCos(wo, wi) * F * 0.25f);
        r.pdf = d.PDF(wo, wm) / (4.f * cos_om) * F;
        return r;
    }
    float denom = cos_im + cos_om / etap;
    float denom2 = denom * denom;
    if (!(denom2 > 0.f)) return r;
    float ft = Dm * (1.f - F) * d.GOverCos(wo, wi) * std::abs(cos_im * cos_om) / denom2;
    if (mode == TransportMode::Radiance) ft /= etap * etap;
    r.f = Color(ft);
    r.pdf = d.PDF(wo, wm) * std::abs(cos_im) / denom2 * (1.f - F);
    return r;
}

}  // namespace

Color DielectricBSDF::f(Vec3 wo, Vec3 wi) const {
    if (IsSpecular() || wo.z == 0.f) return Color(0.f);
    float e = eta_;
    if (wo.z < 0.f) wo = FlipZ(wo), wi = FlipZ(wi), e = 1.f / eta_;
    const Color f = EvalRoughDielectric(distrib_, e, mode_, wo, wi).f;
    return wi.z < 0.f ? f * tint_ : f;
}

float DielectricBSDF::PDF(Vec3 wo, Vec3 wi) const {
    if (IsSpecular() || wo.z == 0.f) return 0.f;
    float e = eta_;
    if (wo.z < 0.f) wo = FlipZ(wo), wi = FlipZ(wi), e = 1.f / eta_;
    return EvalRoughDielectric(distrib_, e, mode_, wo, wi).pdf;
}

std::optional<BSDFSample> DielectricBSDF::Sample_f(Vec3 wo, float uc, Vec2 u) const {
    if (wo.z == 0.f) return std::nullopt;
    bool flip = wo.z < 0.f;
    float e = flip ? 1.f / eta_ : eta_;
    Vec3 w = flip ? FlipZ(wo) : wo;
    auto out = [flip](Vec3 v) { return flip ? FlipZ(v) : v; };

    if (eta_ == 1.f) {
        // Index-matched: no reflection, no bending, no radiance scaling.
        return BSDFSample{tint_ * (1.f / w.z), -wo, 1.f, true, true, 1.f};
    }
    if (distrib_.EffectivelySmooth()) {
        float R = FrDielectric(w.z, e), T = 1.f - R;
        if (uc < R) {
            Vec3 wi = MirrorAboutNormal(w);
            return BSDFSample{Color(R / w.z), out(wi), R, true, false, 1.f};
        }
        Vec3 wi;
        if (!Refract(w, Vec3(0.f, 0.f, 1.f), e, &wi) || !(wi.z < 0.f)) return std::nullopt;
        float ft = T / std::abs(wi.z);
        if (mode_ == TransportMode::Radiance) ft /= e * e;
        return BSDFSample{tint_ * ft, out(wi), T, true, true, e};
    }

    Vec3 wm = distrib_.Sample_wm(w, u);
    float R = FrDielectric(Dot(w, wm), e);
    Vec3 wi;
    bool transmit = uc >= R;
    if (!transmit) {
        wi = Reflect(w, wm);
        if (!(wi.z > 0.f)) return std::nullopt;
    } else {
        if (!Refract(w, wm, e, &wi) || !(wi.z < 0.f)) return std::nullopt;
    }
    RoughDielectricEval ev = EvalRoughDielectric(distrib_, e, mode_, w, wi);
    if (!(ev.pdf > 0.f)) return std::nullopt;
    return BSDFSample{transmit ? ev.f * tint_ : ev.f, out(wi), ev.pdf, false, transmit, transmit ? e : 1.f};
}

}  // namespace tessera
