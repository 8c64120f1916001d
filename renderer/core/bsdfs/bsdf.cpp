#include "bsdf.h"

#include <algorithm>
#include <cmath>

#include "fresnel.h"
#include "ggx_albedo.h"
#include "sampling.h"

namespace tessera {

namespace {

inline Vec3 FlipZ(Vec3 w) { return {w.x, w.y, -w.z}; }
inline Vec3 MirrorAboutNormal(Vec3 w) { return {-w.x, -w.y, w.z}; }
inline float Clamp01(float v) { return std::isfinite(v) ? std::clamp(v, 0.f, 1.f) : 0.f; }
inline Color Clamp01(Color c) { return {Clamp01(c.x), Clamp01(c.y), Clamp01(c.z)}; }
inline Color Lerp(float t, Color a, Color b) { return a * (1.f - t) + b * t; }
// Below this 1 - E1_avg (roughness under ~0.05) the compensation adds < 1e-4 and its
// normalisation would divide by almost nothing: it is left out (both f and the albedos).
constexpr float kMinMsLoss = 1e-4f;

}  // namespace

// ---------------------------------------------------------------------------------------
// DiffuseBSDF

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

// ---------------------------------------------------------------------------------------
// MicrofacetReflection (wo, wi in the upper hemisphere)

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

// ---------------------------------------------------------------------------------------
// ConductorBSDF

namespace {
// Every lobe that can contribute keeps at least this selection weight, so a lobe whose
// albedo estimate at wo is 0 (F0 = 0 at normal incidence) is still sampled and BSDF
// sampling alone stays unbiased.
constexpr float kMinLobeWeight = 0.02f;
}  // namespace

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

// ---------------------------------------------------------------------------------------
// DielectricBSDF. Internally wo is brought to the upper hemisphere by mirroring z and the
// relative index e = n_below / n_above is inverted if wo started inside; every formula
// below then has the incident medium above with index 1 and the other below with index e.

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

// ---------------------------------------------------------------------------------------
// PreviewSurfaceBSDF

namespace {
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
      glass_(std::isfinite(p.ior) && p.ior > 0.f ? p.ior : 1.5f, TrowbridgeReitz::RoughnessToAlpha(p.roughness), mode) {
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

// ---------------------------------------------------------------------------------------

std::optional<Color> ExactLambertianAlbedo(const MaterialParams& p) {
    // Opaque at every hit: the BSDF's own opacity rule, and no cutout or presence holes.
    const bool opaque = p.opacity_threshold == 0.f   ? Clamp01(p.opacity) == 1.f
                        : p.opacity_threshold > 0.f ? !IsCutout(p, p.opacity)
                                                    : p.opacity >= 1.f;
    if (!opaque || Clamp01(p.clearcoat) > 0.f) return std::nullopt;
    const Color base = Clamp01(p.diffuse_color);
    if (p.use_specular_workflow) {
        // F0 = specularColor, F90 = min(1, 50 max F0): both 0 only when F0 is.
        if (!IsBlack(Clamp01(p.specular_color))) return std::nullopt;
        return base;
    }
    const float ior = std::isfinite(p.ior) && p.ior > 0.f ? p.ior : 1.5f;
    if (Clamp01(p.metallic) != 0.f || F0FromIor(ior) != 0.f) return std::nullopt;
    return base;
}

BSDF MakePreviewSurfaceBSDF(const MaterialParams& p, TransportMode mode) {
    const bool cutout_mode = p.opacity_threshold != 0.f;  // or presence mode: opaque where hit
    const float opacity = cutout_mode ? 1.f : Clamp01(p.opacity);
    const float ior = std::isfinite(p.ior) && p.ior > 0.f ? p.ior : 1.5f;
    const float alpha = TrowbridgeReitz::RoughnessToAlpha(p.roughness);
    if (opacity == 0.f) return DielectricBSDF(ior, alpha, mode, Clamp01(p.transmission_tint));
    const bool no_coat = !(Clamp01(p.clearcoat) > 0.f);
    if (opacity == 1.f && no_coat && !p.use_specular_workflow && Clamp01(p.metallic) == 1.f) {
        Color c = Clamp01(p.diffuse_color);
        return ConductorBSDF(c, c, alpha);
    }
    return PreviewSurfaceBSDF(p, mode);
}

}  // namespace tessera
