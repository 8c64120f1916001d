// What the BSDF kinds' tests share (bsdfs/*_bsdf_test.cpp): the chi-square of a kind's
// sampling against its PDF, the agreement of Sample_f with f and PDF, reciprocity, the
// white furnace bound and finiteness at extremes, each run on a kind's own list of cases
// (NamedBSDF) and each with the negative control that shows it can fail. Random numbers
// come from PixelSampler, so every run is identical.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <deque>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "bsdf.h"
#include "chi_square.h"
#include "microfacet.h"
#include "sampler.h"

namespace tessera::testing {

inline Vec3 Dir(float cos_theta, float phi) {
    float s = std::sqrt(std::max(0.f, 1.f - cos_theta * cos_theta));
    return {s * std::cos(phi), s * std::sin(phi), cos_theta};
}

inline std::string Str(Vec3 v) {
    std::ostringstream o;
    o << "(" << v.x << ", " << v.y << ", " << v.z << ")";
    return o.str();
}

struct NamedBSDF {
    std::string name;
    BSDF bsdf;
    bool lossless = false;  // white furnace must give exactly 1 (Importance mode)
};

// A UsdPreviewSurface's inputs, for the kinds the factory makes from them.
inline MaterialParams Preview(float roughness, float metallic, float ior, float clearcoat, bool spec_workflow = false,
                              float opacity = 1.f, Color diffuse = Color(0.8f, 0.5f, 0.2f)) {
    MaterialParams p;
    p.diffuse_color = diffuse;
    p.roughness = roughness;
    p.metallic = metallic;
    p.ior = ior;
    p.clearcoat = clearcoat;
    p.clearcoat_roughness = clearcoat > 0.f ? 0.3f : 0.01f;
    p.use_specular_workflow = spec_workflow;
    p.specular_color = Color(0.9f, 0.6f, 0.3f);
    p.opacity = opacity;
    return p;
}

// Incidence directions, cos θ from normal to grazing; negative = below the horizon (the
// inside of a dielectric, the back of a two-sided opaque surface).
inline constexpr float kCosThetas[] = {1.f, 0.7f, 0.3f, 0.02f, -0.5f, -0.02f};

// --- Chi-square machinery -----------------------------------------------------------------

// 2-point Gauss-Legendre on a (cos θ, φ) rectangle; dω = d(cos θ) dφ, so no Jacobian.
// `zero_and_nonzero` reports whether the nodes saw both pdf = 0 and pdf > 0.
template <typename Pdf>
inline double GaussLegendre2(const Pdf& pdf, double c0, double c1, double p0, double p1, bool* zero_and_nonzero = nullptr) {
    const double g = 0.5 / std::sqrt(3.0);
    double cm = 0.5 * (c0 + c1), pm = 0.5 * (p0 + p1), dc = c1 - c0, dp = p1 - p0;
    double sum = 0.0;
    bool zero = false, nonzero = false;
    for (double a : {-g, g})
        for (double b : {-g, g}) {
            double c = cm + a * dc, phi = pm + b * dp;
            double s = std::sqrt(std::max(0.0, 1.0 - c * c));
            double v = pdf(Vec3(float(s * std::cos(phi)), float(s * std::sin(phi)), float(c)));
            (v > 0.0 ? nonzero : zero) = true;
            sum += v;
        }
    if (zero_and_nonzero) *zero_and_nonzero |= zero && nonzero;
    return sum * 0.25 * dc * dp;
}

struct BinCoord {
    double c, phi;
};
inline BinCoord ToBinCoord(Vec3 w) {
    double phi = std::atan2(double(w.y), double(w.x));
    return {std::clamp(double(w.z), -1.0, 1.0), phi < 0.0 ? phi + 2.0 * kPi : phi};
}

// Adaptive quadrature: split into quadrants until they agree with the whole (relative
// 1e-4, or absolutely to 1% of one sample). GGX lobes at roughness 0.05 (alpha 0.0025) are
// far narrower than a bin, and Gauss points can straddle such a peak without seeing it, so
// a cell that contains a "hint" (a direction where the test knows a lobe peaks) is always
// split further, down to cells well below alpha.
template <typename Pdf>
inline double Adaptive(const Pdf& pdf, double c0, double c1, double p0, double p1, double whole, double abs_tol,
                const std::vector<BinCoord>& hints, int depth, int pole_depth = 0) {
    double cm = 0.5 * (c0 + c1), pm = 0.5 * (p0 + p1);
    // A peak at a pole spans every φ of the cells touching it, so those are split in cos θ
    // only (into thin rings whose pdf is smooth in φ).
    bool at_pole = false;
    for (const BinCoord& h : hints) at_pole |= (h.c >= 1.0 && c1 >= 1.0) || (h.c <= -1.0 && c0 <= -1.0);
    if (at_pole && pole_depth < 24) {
        double lo = GaussLegendre2(pdf, c0, cm, p0, p1), hi = GaussLegendre2(pdf, cm, c1, p0, p1);
        return Adaptive(pdf, c0, cm, p0, p1, lo, abs_tol, hints, depth, pole_depth + 1) +
               Adaptive(pdf, cm, c1, p0, p1, hi, abs_tol, hints, depth, pole_depth + 1);
    }
    if (at_pole) return whole;
    bool edge = false;
    {
        // Corners too (inset, so a pdf that is 0 exactly on a bin edge such as the horizon
        // does not count): a sliver of support along a cell edge can hide from every Gauss point.
        const double e = 1e-3;
        bool zero = false, nonzero = false;
        for (double c : {c0 + e * (c1 - c0), c1 - e * (c1 - c0)})
            for (double phi : {p0 + e * (p1 - p0), p1 - e * (p1 - p0)}) {
                double s = std::sqrt(std::max(0.0, 1.0 - c * c));
                (pdf(Vec3(float(s * std::cos(phi)), float(s * std::sin(phi)), float(c))) > 0.0 ? nonzero : zero) = true;
            }
        edge = zero && nonzero;
    }
    double q[4] = {GaussLegendre2(pdf, c0, cm, p0, pm, &edge), GaussLegendre2(pdf, cm, c1, p0, pm, &edge),
                   GaussLegendre2(pdf, c0, cm, pm, p1, &edge), GaussLegendre2(pdf, cm, c1, pm, p1, &edge)};
    double sum = q[0] + q[1] + q[2] + q[3];
    // A support edge (pdf jumping to 0, e.g. where microfacets turn away) can fool the
    // agreement test: nested Gauss points on both sides of a jump at mid-cell agree while
    // both are wrong. Such cells are refined until they are small.
    if (edge && depth < 8) {
        return Adaptive(pdf, c0, cm, p0, pm, q[0], abs_tol, hints, depth + 1) +
               Adaptive(pdf, cm, c1, p0, pm, q[1], abs_tol, hints, depth + 1) +
               Adaptive(pdf, c0, cm, pm, p1, q[2], abs_tol, hints, depth + 1) +
               Adaptive(pdf, cm, c1, pm, p1, q[3], abs_tol, hints, depth + 1);
    }
    bool hinted = false;
    for (const BinCoord& h : hints) hinted |= std::abs(h.c) < 1.0 && h.c >= c0 && h.c <= c1 && h.phi >= p0 && h.phi <= p1;
    bool converged = std::abs(sum - whole) <= std::max(abs_tol, 1e-4 * std::abs(sum));
    if ((hinted && depth >= 16) || (!hinted && (depth >= 10 || converged))) return sum;
    return Adaptive(pdf, c0, cm, p0, pm, q[0], abs_tol, hints, depth + 1) +
           Adaptive(pdf, cm, c1, p0, pm, q[1], abs_tol, hints, depth + 1) +
           Adaptive(pdf, c0, cm, pm, p1, q[2], abs_tol, hints, depth + 1) +
           Adaptive(pdf, cm, c1, pm, p1, q[3], abs_tol, hints, depth + 1);
}

// Where the lobes of anything tested here can peak, for a given wo: the normals, wo's
// mirror images and its refraction directions for the tested indices.
inline std::vector<BinCoord> PeakHints(Vec3 wo) {
    std::vector<BinCoord> h = {ToBinCoord(Vec3(0, 0, 1)), ToBinCoord(Vec3(0, 0, -1))};
    for (Vec3 w : {wo, Vec3(-wo.x, -wo.y, wo.z), Vec3(-wo.x, -wo.y, -wo.z), Vec3(wo.x, wo.y, -wo.z)}) {
        h.push_back(ToBinCoord(w));
        if (w.z == 0.f) continue;
        for (float eta : {1.33f, 1.5f, 2.4f, 1.f / 1.33f, 1.f / 1.5f, 1.f / 2.4f}) {
            Vec3 n(0, 0, w.z > 0.f ? 1.f : -1.f), wt;
            if (Refract(w, n, eta, &wt)) h.push_back(ToBinCoord(wt));
        }
    }
    return h;
}

inline constexpr int kThetaBins = 16, kPhiBins = 32;

// Histogram of sampled directions over (cos θ, φ) bins of the whole sphere, plus one bin
// for "no direction" (delta lobes, samples lost below the horizon) whose expected count is
// n (1 - ∫ pdf). Expected counts integrate pdf over each bin; pdf_scale lets a test feed a
// deliberately wrong pdf.
template <typename SampleFn, typename PdfFn>
inline ChiSquareResult DirectionsChiSquare(SampleFn sample, PdfFn pdf, const std::vector<BinCoord>& hints, uint32_t seed,
                                    int n = 200000, double pdf_scale = 1.0) {
    const int bins = kThetaBins * kPhiBins;
    std::vector<double> observed(bins + 1, 0.0), expected(bins + 1, 0.0);
    for (int i = 0; i < n; ++i) {
        PixelSampler s(seed, uint64_t(i), 0);
        std::optional<Vec3> w = sample(s);
        if (!w) {
            observed[bins] += 1.0;
            continue;
        }
        float ct = std::clamp(w->z, -1.f, 1.f);
        float phi = std::atan2(w->y, w->x);
        if (phi < 0.f) phi += 2.f * kPi;
        int it = std::clamp(int((ct + 1.f) * 0.5f * kThetaBins), 0, kThetaBins - 1);
        int ip = std::clamp(int(phi / (2.f * kPi) * kPhiBins), 0, kPhiBins - 1);
        observed[it * kPhiBins + ip] += 1.0;
    }
    double total = 0.0;
    const int sub = 4;  // forced sub-cells per bin side, so the adaptive refinement sees narrow peaks
    for (int it = 0; it < kThetaBins; ++it)
        for (int ip = 0; ip < kPhiBins; ++ip) {
            double c0 = -1.0 + 2.0 * it / kThetaBins, dc = 2.0 / kThetaBins / sub;
            double p0 = 2.0 * kPi * ip / kPhiBins, dp = 2.0 * kPi / kPhiBins / sub;
            double integral = 0.0;
            for (int a = 0; a < sub; ++a)
                for (int b = 0; b < sub; ++b) {
                    double ca = c0 + a * dc, pb = p0 + b * dp;
                    double whole = GaussLegendre2(pdf, ca, ca + dc, pb, pb + dp);
                    integral += Adaptive(pdf, ca, ca + dc, pb, pb + dp, whole, 1e-2 / n, hints, 0);
                }
            expected[it * kPhiBins + ip] = n * integral * pdf_scale;
            total += integral * pdf_scale;
        }
    expected[bins] = std::max(0.0, n * (1.0 - total));
    return ChiSquareTest(observed, expected);
}

inline ChiSquareResult BSDFChiSquare(const BSDF& b, Vec3 wo, uint32_t seed, double pdf_scale = 1.0) {
    return DirectionsChiSquare(
        [&](PixelSampler& s) -> std::optional<Vec3> {
            float uc = s.Get1D();
            auto bs = b.Sample_f(wo, uc, s.Get2D());
            if (!bs || bs->is_specular) return std::nullopt;
            return bs->wi;
        },
        [&](Vec3 wi) { return double(b.PDF(wo, wi)); }, PeakHints(wo), seed, 200000, pdf_scale);
}


// --- White furnace --------------------------------------------------------------------------

struct Furnace {
    Color mean, stderr_;
};

// ∫ f |cos θi| dωi for one wo, as the mean of Sample_f's weights f |cos| / pdf (a lost sample
// weighs 0). Transmission weights are multiplied by eta² when the BSDF is in radiance mode,
// since that factor is solid-angle compression, not energy.
inline Furnace WhiteFurnace(const BSDF& b, Vec3 wo, TransportMode mode, int n = 60000) {
    Color sum(0.f), sum2(0.f);
    for (int i = 0; i < n; ++i) {
        PixelSampler s(31, uint64_t(i), 0);
        float uc = s.Get1D();
        auto bs = b.Sample_f(wo, uc, s.Get2D());
        if (!bs) continue;
        Color w = bs->f * (std::abs(bs->wi.z) / bs->pdf);
        if (bs->is_transmission && mode == TransportMode::Radiance) w *= bs->eta * bs->eta;
        sum += w;
        sum2 += w * w;
    }
    Color mean = sum / float(n);
    Color var = sum2 / float(n) - mean * mean;
    return {mean, Color(std::sqrt(std::max(0.f, var.x) / n), std::sqrt(std::max(0.f, var.y) / n),
                        std::sqrt(std::max(0.f, var.z) / n))};
}

// --- The checks every kind runs on its cases ---------------------------------------------

// (a) Sample_f's directions follow PDF (chi-square over the sphere, a bin for "no
// direction"), at every kCosThetas incidence of every case with a non-delta lobe. Negative
// control: the same test with the pdf 10 % too high fails on the first such case (the
// smallest error shown detected; shape errors are shown by BsdfChecks.ChiSquareSeesShape).
inline void ExpectSamplingFollowsPdf(const std::vector<NamedBSDF>& cases, uint32_t seed) {
    int tested = 0;
    for (const NamedBSDF& c : cases) {
        if (!c.bsdf.IsNonSpecular()) continue;  // delta-only: tested by the kind's own lobe-choice test
        for (float ct : kCosThetas) {
            Vec3 wo = Dir(ct, 1.1f);
            auto r = BSDFChiSquare(c.bsdf, wo, ++seed);
            ++tested;
            EXPECT_TRUE(r.pass) << c.name << " wo " << Str(wo) << ": chi2 " << r.statistic << " dof " << r.dof;
            if (tested == 1) {
                EXPECT_FALSE(BSDFChiSquare(c.bsdf, wo, seed, 1.1).pass) << c.name << ": a pdf 10 % high must fail";
            }
        }
    }
    EXPECT_GT(tested, 0);
}

// (b) A non-delta sample's f and pdf are f(wo, wi) and PDF(wo, wi); a delta lobe is
// invisible to f and PDF; is_transmission says which side wi is on.
inline void ExpectSampleReturnsFAndPdf(const std::vector<NamedBSDF>& cases) {
    for (const NamedBSDF& c : cases)
        for (float ct : kCosThetas) {
            Vec3 wo = Dir(ct, 2.3f);
            for (int i = 0; i < 2000; ++i) {
                PixelSampler s(5, uint64_t(i), 1);
                float uc = s.Get1D();
                auto bs = c.bsdf.Sample_f(wo, uc, s.Get2D());
                if (!bs) continue;
                ASSERT_NEAR(Length(bs->wi), 1.f, 1e-4f) << c.name;
                ASSERT_GT(bs->pdf, 0.f) << c.name;
                EXPECT_EQ(bs->is_transmission, bs->wi.z * wo.z < 0.f) << c.name;
                if (bs->is_specular) {
                    // Delta lobes are invisible to f and PDF (a mixture's other lobes are not).
                    if (!c.bsdf.IsNonSpecular()) EXPECT_EQ(c.bsdf.PDF(wo, bs->wi), 0.f) << c.name;
                    continue;
                }
                Color f = c.bsdf.f(wo, bs->wi);
                float pdf = c.bsdf.PDF(wo, bs->wi);
                for (int k = 0; k < 3; ++k)
                    ASSERT_NEAR(bs->f[k], f[k], 2e-3f * std::max(1.f, f[k])) << c.name << " wo " << Str(wo);
                ASSERT_NEAR(bs->pdf, pdf, 2e-3f * std::max(1.f, pdf)) << c.name << " wo " << Str(wo);
            }
        }
}

// (c) Reflection is symmetric, f(wo, wi) == f(wi, wo), for wo and wi on one side.
inline void ExpectReflectionIsSymmetric(const std::vector<NamedBSDF>& cases) {
    for (const NamedBSDF& c : cases)
        for (int i = 0; i < 3000; ++i) {
            PixelSampler s(9, uint64_t(i), 0);
            float side = s.Get1D() < 0.5f ? 1.f : -1.f;
            Vec3 wo = Dir(side * std::max(1e-3f, s.Get1D()), 2.f * kPi * s.Get1D());
            Vec3 wi = Dir(side * std::max(1e-3f, s.Get1D()), 2.f * kPi * s.Get1D());
            Color a = c.bsdf.f(wo, wi), b = c.bsdf.f(wi, wo);
            for (int k = 0; k < 3; ++k)
                ASSERT_NEAR(a[k], b[k], 1e-3f * std::max({1.f, a[k], b[k]})) << c.name << Str(wo) << Str(wi);
        }
}

// (d) White materials (cases made with white = true) reflect at most 1 at every incidence,
// and exactly 1 where the case says it is lossless, to 5 standard errors. Negative control:
// the bound must catch the case that keeps the most energy made 3 % brighter.
inline void ExpectWhiteFurnaceAtMostOne(const std::vector<NamedBSDF>& white_cases, TransportMode mode) {
    float best = 0.f, best_bound = 0.f;
    for (const NamedBSDF& c : white_cases)
        for (float ct : kCosThetas) {
            Vec3 wo = Dir(ct, 0.9f);
            Furnace fu = WhiteFurnace(c.bsdf, wo, mode);
            for (int k = 0; k < 3; ++k) {
                const float bound = 1.f + 5.f * fu.stderr_[k] + 1e-4f;
                EXPECT_LE(fu.mean[k], bound) << c.name << " cos " << ct;
                if (c.lossless) EXPECT_NEAR(fu.mean[k], 1.f, 5.f * fu.stderr_[k] + 1e-4f) << c.name << " cos " << ct;
                if (fu.mean[k] > best) best = fu.mean[k], best_bound = 1.f + 5.f * 1.03f * fu.stderr_[k] + 1e-4f;
            }
        }
    EXPECT_GT(1.03f * best, best_bound) << "negative control: a 3 % gain must be seen (best case reflects " << best
                                        << ")";
}

// (e) No NaN or Inf, and no negative value, from f, PDF, Sample_f and Albedo at extreme
// directions (on the horizon, a hair off it, at the poles) and extreme random numbers.
inline void ExpectFiniteAtExtremes(const std::vector<NamedBSDF>& cases) {
    const float tiny = 1e-7f;
    const std::vector<Vec3> dirs = {Vec3(1, 0, 0),  // exactly on the horizon
                                    Normalize(Vec3(1, 0, tiny)),  Normalize(Vec3(0.3f, 1, -tiny)),
                                    Dir(0.02f, 0.1f), Dir(-0.02f, 4.f), Vec3(0, 0, 1), Vec3(0, 0, -1),
                                    Dir(0.5f, 3.f), Dir(-0.7f, 1.f)};
    const float us[] = {0.f, 0.5f, 0x1.fffffep-1f};
    for (const NamedBSDF& c : cases)
        for (Vec3 wo : dirs) {
            for (Vec3 wi : dirs) {
                Color f = c.bsdf.f(wo, wi);
                float pdf = c.bsdf.PDF(wo, wi);
                ASSERT_TRUE(IsFinite(f) && f.x >= 0.f && f.y >= 0.f && f.z >= 0.f) << c.name << Str(wo) << Str(wi);
                ASSERT_TRUE(std::isfinite(pdf) && pdf >= 0.f) << c.name << Str(wo) << Str(wi);
            }
            for (float uc : us)
                for (float u0 : us)
                    for (float u1 : us) {
                        auto bs = c.bsdf.Sample_f(wo, uc, Vec2{u0, u1});
                        if (wo.z == 0.f) EXPECT_FALSE(bs) << c.name;
                        if (!bs) continue;
                        ASSERT_TRUE(IsFinite(bs->f) && IsFinite(bs->wi) && std::isfinite(bs->pdf) && bs->pdf > 0.f &&
                                    std::isfinite(bs->eta) && bs->eta > 0.f)
                            << c.name << Str(wo) << " " << uc << " " << u0 << " " << u1;
                        ASSERT_NEAR(Length(bs->wi), 1.f, 1e-3f) << c.name;
                    }
            EXPECT_TRUE(IsFinite(c.bsdf.Albedo()));
        }
}

// A kind's tests run the five on its cases, make_cases(mode, white) listing them (white:
// every colour 1), in three tests: (a) and (d) are long statistical tests
// (scripts/cpp-long-tests.txt), (b), (c) and (e) their short stand-ins in the quick tier.
template <typename MakeCases>
void ExpectSamplingFollowsPdf(const MakeCases& make_cases, uint32_t seed) {
    ExpectSamplingFollowsPdf(make_cases(TransportMode::Radiance, false), seed);
}
template <typename MakeCases>
void ExpectWhiteFurnaceAtMostOne(const MakeCases& make_cases) {
    for (TransportMode mode : {TransportMode::Radiance, TransportMode::Importance})
        ExpectWhiteFurnaceAtMostOne(make_cases(mode, true), mode);
}
template <typename MakeCases>
void ExpectConsistentReciprocalAndFinite(const MakeCases& make_cases) {
    for (TransportMode mode : {TransportMode::Radiance, TransportMode::Importance})
        ExpectSampleReturnsFAndPdf(make_cases(mode, false));
    ExpectReflectionIsSymmetric(make_cases(TransportMode::Radiance, false));
    ExpectFiniteAtExtremes(make_cases(TransportMode::Radiance, false));
}

// --- Energy estimates ----------------------------------------------------------------------

struct Estimate {
    double mean = 0, se = 0;
};

// ∫ f(wo, wi) |cos θi| dωi of channel c, as the mean of Sample_f's weights f |cos| / pdf.
// Sample_f's f and pdf are the BSDF's own f and PDF (checked by ExpectSampleReturnsFAndPdf
// and the chi-square), so this is the directional albedo of f, not of a formula beside it.
template <typename B>
Estimate Albedo(const B& b, Vec3 wo, int c = 0, int n = 20000, uint32_t seed = 7) {
    double sum = 0, sum2 = 0;
    for (int i = 0; i < n; ++i) {
        PixelSampler s(seed, uint64_t(i), 0);
        float uc = s.Get1D();
        auto bs = b.Sample_f(wo, uc, s.Get2D());
        if (!bs) continue;
        double w = bs->f[c] * std::abs(bs->wi.z) / bs->pdf;
        sum += w;
        sum2 += w * w;
    }
    double mean = sum / n;
    return {mean, std::sqrt(std::max(0.0, sum2 / n - mean * mean) / n)};
}

// View cosines of the energy tests, from head-on to 89 degrees.
inline constexpr float kViewCos[] = {1.f, 0.8f, 0.5f, 0.25f, 0.1f, 0.0175f};

}  // namespace tessera::testing
