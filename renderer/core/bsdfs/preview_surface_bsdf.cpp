#include "preview_surface_bsdf.h"

#include <algorithm>
#include <cmath>

#include "fresnel.h"
#include "sampling.h"

namespace tessera {

namespace {
inline Color Lerp(float t, Color a, Color b) { return a * (1.f - t) + b * t; }
constexpr float kCoatF0 = 0.04f;  // clearcoat is a fixed ior-1.5 layer, as in Storm
// Grazing reflectance of a dielectric specular layer with normal reflectance F0: 1 for any
// real interface (F0 >= 0.02, ior >= 1.33), falling to 0 with F0 so that ior 1 or
// specularColor 0 (no interface: the exact Fresnel is 0 at every angle) has no specular.
// The rule Filament and Unreal use; Storm keeps F90 = 1.
inline float DielectricF90(Color f0) { return std::min(1.f, 50.f * MaxComponent(f0)); }
}  // namespace

PreviewSurfaceBSDF::PreviewSurfaceBSDF(const MaterialParams& p, TransportMode mode)
    : spec_{TrowbridgeReitz(0.f), Color(0.f), Color(0.f)},
      coat_{TrowbridgeReitz(TrowbridgeReitz::RoughnessToAlpha(p.clearcoat_roughness)), Color(kCoatF0), Color(1.f)},
      clearcoat_(Clamp01(p.clearcoat)),
      opacity_(p.opacity_threshold != 0.f ? 1.f : Clamp01(p.opacity)),  // cutout or presence: opaque
      glass_(SanitisedIor(p), TrowbridgeReitz::RoughnessToAlpha(p.roughness), mode) {
    const float alpha = TrowbridgeReitz::RoughnessToAlpha(p.roughness);
    const Color base = Clamp01(p.diffuse_color);
    if (p.use_specular_workflow) {
        diffuse_albedo_ = base;
        const Color f0 = Clamp01(p.specular_color);
        spec_ = {TrowbridgeReitz(alpha), f0, Color(DielectricF90(f0))};
    } else {
        const float m = Clamp01(p.metallic);
        const Color f0 = Color(F0FromIor(glass_.eta()));
        diffuse_albedo_ = base * (1.f - m);
        spec_ = {TrowbridgeReitz(alpha), Lerp(m, f0, base), Lerp(m, Color(DielectricF90(f0)), base)};
    }
    // Albedo scaling: ρ/pi (1 - Es(wo)) (1 - Es(wi)) / (1 - Es_avg), with the average folded
    // into the stored colour. A channel whose specular reflects everything has no diffuse.
    const Color loss_avg = Color(1.f) - spec_.AverageAlbedo();
    auto scaled = [](float rho, float loss) { return loss > 1e-6f ? rho / loss : 0.f; };
    diffuse_ = {scaled(diffuse_albedo_.x, loss_avg.x), scaled(diffuse_albedo_.y, loss_avg.y),
                scaled(diffuse_albedo_.z, loss_avg.z)};
    if (IsBlack(diffuse_)) diffuse_albedo_ = Color(0.f);
    flags_ = ComputeFlags();
}

PreviewSurfaceBSDF::TableNode PreviewSurfaceBSDF::NodeOf(float mu) {
    // As LookupGGXAlbedo places mu among the GGX tables' nodes.
    constexpr int n = PreviewSurfaceTable::kNodes;
    const float t = std::sqrt(std::clamp(mu, 0.f, 1.f)) * float(n - 1);
    const int i = std::min(int(t), n - 2);
    return {i, t - float(i)};
}

PreviewSurfaceTable PreviewSurfaceBSDF::Tabulate() const {
    PreviewSurfaceBSDF direct = *this;
    direct.UseTable(nullptr);
    PreviewSurfaceTable t{};
    constexpr int n = PreviewSurfaceTable::kNodes;
    for (int i = 0; i < n; ++i) {
        const float node = float(i) / float(n - 1);
        const float mu = node * node;
        direct.LobeProbabilities(Vec3(0.f, 0.f, mu), t.p[i]);
        const GGXAlbedo e = spec_.Table(mu);
        t.diffuse_scale[i] = DiffuseScale(mu, e);
        t.ms_loss[i] = std::max(0.f, 1.f - e.e1);
        t.coat_atten[i] = CoatAttenuation(mu);
    }
    return t;
}

float PreviewSurfaceBSDF::CoatAttenuation(float mu) const {
    return clearcoat_ > 0.f ? 1.f - clearcoat_ * coat_.Albedo(mu).x : 1.f;
}

Color PreviewSurfaceBSDF::DiffuseScale(float mu) const { return DiffuseScale(mu, spec_.Table(mu)); }

Color PreviewSurfaceBSDF::DiffuseScale(float mu, GGXAlbedo e) const {
    return Clamp01(Color(1.f) - (spec_.SingleAlbedo(mu, e) + spec_.MultiAlbedo(e)));
}

uint32_t PreviewSurfaceBSDF::ComputeFlags() const {
    uint32_t flags = 0;
    if (opacity_ > 0.f) {
        flags |= kBSDFReflection;
        flags |= spec_.distrib.EffectivelySmooth() ? kBSDFSpecular : kBSDFGlossy;
        if (clearcoat_ > 0.f) flags |= coat_.distrib.EffectivelySmooth() ? kBSDFSpecular : kBSDFGlossy;
        if (!IsBlack(diffuse_) || !IsBlack(spec_.Fms()) || (clearcoat_ > 0.f && !IsBlack(coat_.Fms())))
            flags |= kBSDFDiffuse;  // the cosine lobe also carries the multiple scattering
    }
    if (opacity_ < 1.f) flags |= glass_.Flags();
    return flags;
}

Color PreviewSurfaceBSDF::Albedo() const {
    // The directional albedo at normal incidence (the coat's interreflection with the base
    // is left out, as in the BSDF).
    const float ac = CoatAttenuation(1.f);
    Color opaque = Color(1.f - ac) + ac * (spec_.Albedo(1.f) + DiffuseScale(1.f) * diffuse_albedo_);
    return opaque * opacity_ + Color(1.f - opacity_);
}

void PreviewSurfaceBSDF::LobeProbabilities(Vec3 wo, float p[kNumLobes]) const {
    const float mu = std::abs(wo.z);
    if (mu == cached_mu_) {
        for (int i = 0; i < kNumLobes; ++i) p[i] = cached_p_[i];
        return;
    }
    if (table_) {
        const TableNode n = NodeOf(mu);
        for (int i = 0; i < kNumLobes; ++i) {
            const float a = table_->p[n.i][i], b = table_->p[n.i + 1][i];
            p[i] = a + (b - a) * n.ft;
        }
        cached_mu_ = mu;
        for (int i = 0; i < kNumLobes; ++i) cached_p_[i] = p[i];
        return;
    }
    // The cosine lobe carries the diffuse and both multiple-scattering terms.
    const float ac = CoatAttenuation(mu);
    const bool has_coat = clearcoat_ > 0.f;
    const bool has_spec = !(IsBlack(spec_.f0) && IsBlack(spec_.f90));
    const bool has_cosine = (Flags() & kBSDFDiffuse) != 0;
    const GGXAlbedo e = spec_.Table(mu);
    const Color cosine = spec_.MultiAlbedo(e) + DiffuseScale(mu, e) * diffuse_albedo_;
    p[kCoat] = has_coat ? std::max(kMinLobeWeight, clearcoat_ * coat_.SingleAlbedo(mu).x) : 0.f;
    p[kSpec] = has_spec ? std::max(kMinLobeWeight, ac * Luminance(spec_.SingleAlbedo(mu, e))) : 0.f;
    p[kDiffuse] = has_cosine ? std::max(kMinLobeWeight, ac * Luminance(cosine) +
                                                            (has_coat ? clearcoat_ * coat_.MultiAlbedo(mu).x : 0.f))
                             : 0.f;
    for (int i = 0; i < kGlass; ++i) p[i] *= opacity_;
    p[kGlass] = 1.f - opacity_;
    float sum = 0.f;
    for (int i = 0; i < kNumLobes; ++i) sum += p[i];
    for (int i = 0; i < kNumLobes; ++i) p[i] = sum > 0.f ? p[i] / sum : 0.f;
    cached_mu_ = mu;
    for (int i = 0; i < kNumLobes; ++i) cached_p_[i] = p[i];
}

Color PreviewSurfaceBSDF::OpaqueF(Vec3 wo, Vec3 wi) const {
    Color base(0.f);
    const bool rough = !spec_.distrib.EffectivelySmooth();
    if (IsBlack(diffuse_) && !rough) return OverCoat(base, wo, wi);
    if (table_) {
        const TableNode no = NodeOf(wo.z), ni = NodeOf(wi.z);
        if (!IsBlack(diffuse_))
            base = Interpolate(table_->diffuse_scale, no) * Interpolate(table_->diffuse_scale, ni) * diffuse_ * kInvPi;
        if (rough)
            base += spec_.f(wo, wi) + spec_.fms(wo, wi, Interpolate(table_->ms_loss, no), Interpolate(table_->ms_loss, ni));
        if (!(clearcoat_ > 0.f)) return base;
        return OverCoat(base, wo, wi, Interpolate(table_->coat_atten, no), Interpolate(table_->coat_atten, ni));
    }
    const GGXAlbedo eo = spec_.Table(wo.z), ei = spec_.Table(wi.z);
    if (!IsBlack(diffuse_)) base = DiffuseScale(wo.z, eo) * DiffuseScale(wi.z, ei) * diffuse_ * kInvPi;
    if (rough) base += spec_.f(wo, wi) + spec_.fms(wo, wi, eo, ei);
    return OverCoat(base, wo, wi);
}

Color PreviewSurfaceBSDF::OverCoat(Color base, Vec3 wo, Vec3 wi) const {
    if (!(clearcoat_ > 0.f)) return base;
    return OverCoat(base, wo, wi, CoatAttenuation(wo.z), CoatAttenuation(wi.z));
}

Color PreviewSurfaceBSDF::OverCoat(Color base, Vec3 wo, Vec3 wi, float atten_o, float atten_i) const {
    Color result = base * (atten_o * atten_i);
    if (!coat_.distrib.EffectivelySmooth()) result += (coat_.f(wo, wi) + coat_.fms(wo, wi)) * clearcoat_;
    return result;
}

Color PreviewSurfaceBSDF::f(Vec3 wo, Vec3 wi) const {
    if (wo.z == 0.f) return Color(0.f);
    Color result(0.f);
    if (opacity_ > 0.f && SameHemisphere(wo, wi)) {
        Vec3 o = wo.z < 0.f ? FlipZ(wo) : wo, i = wo.z < 0.f ? FlipZ(wi) : wi;
        result += OpaqueF(o, i) * opacity_;
    }
    if (opacity_ < 1.f) result += glass_.f(wo, wi) * (1.f - opacity_);
    return result;
}

float PreviewSurfaceBSDF::LobePdf(int lobe, Vec3 wo, Vec3 wi) const {
    if (lobe == kGlass) return glass_.PDF(wo, wi);
    if (!SameHemisphere(wo, wi)) return 0.f;
    if (wo.z < 0.f) wo = FlipZ(wo), wi = FlipZ(wi);
    switch (lobe) {
        case kCoat: return coat_.distrib.EffectivelySmooth() ? 0.f : coat_.PDF(wo, wi);
        case kSpec: return spec_.distrib.EffectivelySmooth() ? 0.f : spec_.PDF(wo, wi);
        default: return CosineHemispherePdf(wi.z);
    }
}

float PreviewSurfaceBSDF::PDF(Vec3 wo, Vec3 wi) const {
    if (wo.z == 0.f) return 0.f;
    float p[kNumLobes];
    LobeProbabilities(wo, p);
    float pdf = 0.f;
    for (int i = 0; i < kNumLobes; ++i)
        if (p[i] > 0.f) pdf += p[i] * LobePdf(i, wo, wi);
    return pdf;
}

std::optional<BSDFSample> PreviewSurfaceBSDF::Sample_f(Vec3 wo, float uc, Vec2 u) const {
    if (wo.z == 0.f) return std::nullopt;
    float p[kNumLobes];
    LobeProbabilities(wo, p);
    int lobe = 0;
    float cdf = 0.f;
    for (; lobe < kNumLobes - 1; ++lobe) {
        if (uc < cdf + p[lobe]) break;
        cdf += p[lobe];
    }
    while (p[lobe] == 0.f && lobe > 0) --lobe;  // rounding pushed uc past the last non-empty lobe
    if (!(p[lobe] > 0.f)) return std::nullopt;
    const float uc_lobe = std::clamp((uc - cdf) / p[lobe], 0.f, 0x1.fffffep-1f);

    const bool flip = wo.z < 0.f;
    const Vec3 w = flip ? FlipZ(wo) : wo;
    auto out = [flip](Vec3 v) { return flip ? FlipZ(v) : v; };
    Vec3 wi;
    switch (lobe) {
        case kCoat:
        case kSpec: {
            const MicrofacetReflection& l = lobe == kCoat ? coat_ : spec_;
            if (l.distrib.EffectivelySmooth()) {
                const float ac = CoatAttenuation(w.z);
                // Mirror direction: wi.z == wo.z, so each attenuation appears squared.
                Color value = lobe == kCoat ? l.F(w.z) * clearcoat_ : l.F(w.z) * (ac * ac);
                return BSDFSample{value * (opacity_ / w.z), out(MirrorAboutNormal(w)), p[lobe], true, false, 1.f};
            }
            if (!l.Sample(w, u, &wi)) return std::nullopt;
            wi = out(wi);
            break;
        }
        case kDiffuse:
            wi = out(SampleCosineHemisphere(u));
            break;
        default: {
            auto bs = glass_.Sample_f(wo, uc_lobe, u);
            if (!bs) return std::nullopt;
            if (bs->is_specular) {
                bs->f *= 1.f - opacity_;
                bs->pdf *= p[kGlass];
                return bs;
            }
            wi = bs->wi;
        }
    }
    float pdf = PDF(wo, wi);
    if (!(pdf > 0.f)) return std::nullopt;
    const bool transmission = !SameHemisphere(wo, wi);
    const float eta = transmission ? (wo.z > 0.f ? glass_.eta() : 1.f / glass_.eta()) : 1.f;
    return BSDFSample{f(wo, wi), wi, pdf, false, transmission, eta};
}

}  // namespace tessera
