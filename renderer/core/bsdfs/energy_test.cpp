// Energy tests of the UsdPreviewSurface layering and the GGX multiple-scattering
// compensation (docs/materials.md, "Energy conservation"). Every statistical check states
// the smallest error it detects and proves it with a negative control: the same check on a
// variant perturbed by that much fails. Random numbers come from PixelSampler: every run
// is identical.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "bsdf.h"
#include "ggx_albedo.h"
#include "microfacet.h"
#include "sampler.h"

using namespace tessera;

namespace {

Vec3 Dir(float cos_theta, float phi) {
    float s = std::sqrt(std::max(0.f, 1.f - cos_theta * cos_theta));
    return {s * std::cos(phi), s * std::sin(phi), cos_theta};
}

struct Estimate {
    double mean = 0, se = 0;
};

// ∫ f(wo, wi) |cos θi| dωi of channel c, as the mean of Sample_f's weights f |cos| / pdf.
// Sample_f's f and pdf are the BSDF's own f and PDF (checked by BsdfConsistency and the
// chi-square tests), so this is the directional albedo of f, not of a formula beside it.
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

MaterialParams Plastic(float roughness, float ior, Color diffuse) {
    MaterialParams p;
    p.diffuse_color = diffuse;
    p.roughness = roughness;
    p.metallic = 0.f;
    p.ior = ior;
    return p;
}

const float kViewCos[] = {1.f, 0.8f, 0.5f, 0.25f, 0.1f, 0.0175f /* 89 degrees */};

}  // namespace

// --- the table -----------------------------------------------------------------------------

// The table (generated in numpy from the GGX/Smith formulas) against an integral of the
// C++ lobe itself (MicrofacetReflection::f, sampled by visible normals on a jittered
// 700 x 700 grid of strata: a stratified Monte-Carlo estimate whose error is far below its
// i.i.d. standard error), F = 1 (E1) and F = (1 - wo·wm)^5 (E5). Tolerance 1e-3 absolute;
// detects a table entry off by 1 % (the negative control scales the table value by 1.01
// and must fail at every point, the smallest E1 checked being 0.3).
TEST(GGXAlbedoTable, MatchesMonteCarloOfTheCppLobe) {
    int checked = 0;
    for (float rough : {0.1f, 0.2f, 0.35f, 0.5f, 0.75f, 1.f})
        for (float mu : {1.f, 0.7f, 0.4f, 0.2f, 0.08f}) {
            const float alpha = TrowbridgeReitz::RoughnessToAlpha(rough);
            MicrofacetReflection e1{TrowbridgeReitz(alpha), Color(1.f), Color(1.f)};
            MicrofacetReflection e5{TrowbridgeReitz(alpha), Color(0.f), Color(1.f)};
            const Vec3 wo = Dir(mu, 0.4f);
            double s1 = 0, s5 = 0;
            const int k = 700, n = k * k;
            for (int i = 0; i < n; ++i) {
                PixelSampler s(3, uint64_t(i), 0);
                Vec2 j = s.Get2D();
                Vec2 u{(float(i % k) + j.x) / k, (float(i / k) + j.y) / k};
                Vec3 wi;
                if (!e1.Sample(wo, u, &wi)) continue;
                float pdf = e1.PDF(wo, wi);
                if (!(pdf > 0.f)) continue;
                s1 += e1.f(wo, wi).x * wi.z / pdf;
                s5 += e5.f(wo, wi).x * wi.z / pdf;
            }
            const double m1 = s1 / n, m5 = s5 / n;
            const GGXAlbedo t = LookupGGXAlbedo(mu, alpha);
            const double tol = 1e-3;
            EXPECT_NEAR(t.e1, m1, tol) << "roughness " << rough << " mu " << mu;
            EXPECT_NEAR(t.e5, m5, tol) << "roughness " << rough << " mu " << mu;
            EXPECT_GT(std::abs(1.01 * t.e1 - m1), tol) << "negative control: 1 % off must be seen";
            ++checked;
        }
    EXPECT_EQ(checked, 30);
}

// E_avg(r) is the exact cosine-weighted integral of the interpolant LookupGGXAlbedo uses
// (that is what makes the albedo-scaled layers integrate exactly). Deterministic: fine
// midpoint rule in t = sqrt(mu), where the interpolant is piecewise linear.
TEST(GGXAlbedoTable, AveragesIntegrateTheInterpolant) {
    for (float rough : {0.f, 0.1f, 0.33f, 0.5f, 0.8f, 1.f}) {
        const float alpha = rough * rough;
        double s1 = 0, s5 = 0;
        const int n = 20000;
        for (int i = 0; i < n; ++i) {
            double t = (i + 0.5) / n, mu = t * t;  // 2 mu dmu = 4 t^3 dt
            GGXAlbedo e = LookupGGXAlbedo(float(mu), alpha);
            s1 += e.e1 * 4 * t * t * t / n;
            s5 += e.e5 * 4 * t * t * t / n;
        }
        GGXAlbedo a = LookupGGXAverage(alpha);
        EXPECT_NEAR(a.e1, s1, 2e-5) << rough;
        EXPECT_NEAR(a.e5, s5, 2e-5) << rough;
    }
    // Known value: a rough (alpha = 1) GGX lobe with F = 1 reflects 1 - ln 2 head-on.
    EXPECT_NEAR(LookupGGXAlbedo(1.f, 1.f).e1, 1.0 - std::log(2.0), 1e-4);
}

// --- white furnace of the PreviewSurface ---------------------------------------------------

// metallic 0, diffuse 1: the directional albedo is 1 for every roughness, ior and view
// angle, to 0.5 %. Detects a 1 % loss anywhere on the grid: each estimate has se < 0.1 %,
// and the negative control (the same check on the albedo scaled by 0.99) must fail at
// every grid point.
TEST(PreviewSurfaceEnergy, WhiteFurnaceIsOneForEveryRoughnessIorAndAngle) {
    double worst = 0;
    for (float rough : {0.f, 0.05f, 0.1f, 0.2f, 0.3f, 0.5f, 0.7f, 0.85f, 1.f})
        for (float ior : {1.f, 1.1f, 1.33f, 1.5f, 2.f, 2.5f, 3.f})
            for (float ct : kViewCos) {
                PreviewSurfaceBSDF b(Plastic(rough, ior, Color(1.f)), TransportMode::Radiance);
                Estimate e = Albedo(b, Dir(ct, 1.3f), 0, 80000);
                ASSERT_LT(e.se, 1.5e-3) << "too noisy";
                EXPECT_NEAR(e.mean, 1.0, 0.005) << "roughness " << rough << " ior " << ior << " cos " << ct;
                EXPECT_GT(std::abs(0.99 * e.mean - 1.0), 0.005) << "negative control";
                worst = std::max(worst, std::abs(e.mean - 1.0));
            }
    std::printf("max |furnace - 1| over the grid: %.5f\n", worst);
}

// The coat keeps energy bounded: a white plastic under a full clearcoat reflects at most 1.
TEST(PreviewSurfaceEnergy, ClearcoatStaysBelowOne) {
    for (float rough : {0.f, 0.3f, 1.f})
        for (float ct : kViewCos) {
            MaterialParams p = Plastic(rough, 1.5f, Color(1.f));
            p.clearcoat = 1.f;
            p.clearcoat_roughness = 0.2f;
            Estimate e = Albedo(PreviewSurfaceBSDF(p, TransportMode::Radiance), Dir(ct, 0.2f));
            EXPECT_LE(e.mean, 1.0 + 4 * e.se + 1e-3) << rough << " " << ct;
            // Most of it is kept away from grazing; at grazing the base's light crosses a
            // strongly reflecting coat twice (the coat's interreflection is not modelled).
            if (ct >= 0.25f) EXPECT_GT(e.mean, 0.9) << rough << " " << ct;
        }
}

// --- plain diffuse materials are Lambert -------------------------------------------------

// specularColor 0 (specular workflow) or ior 1 (metallic workflow) with roughness 1:
// f π / ρ = 1 within 1 % for view and light up to 80°, and the albedo is ρ within 1 % at
// every view angle. Detects 1 %: the negative control runs the same checks on f · 0.99.
TEST(PreviewSurfaceEnergy, NoSpecularIsLambert) {
    const Color rho(0.63f, 0.065f, 0.05f);  // the Cornell box's red
    MaterialParams spec_wf = Plastic(1.f, 1.5f, rho);
    spec_wf.use_specular_workflow = true;
    spec_wf.specular_color = Color(0.f);
    MaterialParams ior1 = Plastic(1.f, 1.f, rho);
    for (const MaterialParams& p : {spec_wf, ior1}) {
        PreviewSurfaceBSDF b(p, TransportMode::Radiance);
        const float cos80 = std::cos(80.f * kPi / 180.f);
        for (float co : {1.f, 0.7f, 0.4f, cos80})
            for (float ci : {1.f, 0.7f, 0.4f, cos80})
                for (float phi : {0.f, 1.f, 3.1f}) {
                    Color f = b.f(Dir(co, 0.f), Dir(ci, phi));
                    for (int c = 0; c < 3; ++c) {
                        double ratio = f[c] * kPi / rho[c];
                        EXPECT_NEAR(ratio, 1.0, 0.01) << co << " " << ci << " channel " << c;
                        EXPECT_GT(std::abs(0.99 * ratio - 1.0), 0.005) << "negative control";
                    }
                }
        for (float ct : kViewCos) {
            Estimate e = Albedo(b, Dir(ct, 0.5f), 0);
            ASSERT_LT(e.se, 1e-3 * rho.x);
            EXPECT_NEAR(e.mean / rho.x, 1.0, 0.01) << ct;
            EXPECT_GT(std::abs(0.99 * e.mean / rho.x - 1.0), 0.005) << "negative control";
        }
    }
}

// --- conductors --------------------------------------------------------------------------

// A white metal reflects (almost) everything at every roughness once multiple scattering is
// compensated: >= 0.97 at roughness 1 (single scattering alone gives 0.31 head-on, the
// negative control), and 1 within 1 % wherever the lobe is rough (Kulla-Conty with F = 1 is
// exactly 1 up to the table).
TEST(ConductorEnergy, WhiteMetalReflectsOne) {
    for (float rough : {0.1f, 0.3f, 0.6f, 1.f})
        for (float ct : kViewCos) {
            // At roughness 0.1 and grazing view the compensation lobe is concentrated at
            // grazing wi while it is sampled with the cosine lobe: too noisy for 1 % here.
            if (rough < 0.3f && ct < 0.1f) continue;
            ConductorBSDF metal(Color(1.f), Color(1.f), TrowbridgeReitz::RoughnessToAlpha(rough));
            Estimate e = Albedo(metal, Dir(ct, 2.f), 0, 80000);
            ASSERT_LT(e.se, 2e-3) << "roughness " << rough << " cos " << ct;
            EXPECT_NEAR(e.mean, 1.0, 0.01) << "roughness " << rough << " cos " << ct;
            if (rough == 1.f) EXPECT_GE(e.mean, 0.97);
        }
    // Negative control: the single-scattering lobe alone is far below 0.97 at roughness 1.
    MicrofacetReflection single{TrowbridgeReitz(1.f), Color(1.f), Color(1.f)};
    double sum = 0;
    const int n = 20000;
    for (int i = 0; i < n; ++i) {
        PixelSampler s(5, uint64_t(i), 0);
        Vec3 wi, wo(0, 0, 1);
        if (!single.Sample(wo, s.Get2D(), &wi)) continue;
        sum += single.f(wo, wi).x * wi.z / single.PDF(wo, wi);
    }
    EXPECT_LT(sum / n, 0.97);
    EXPECT_NEAR(sum / n, 1.0 - std::log(2.0), 0.01);
}

// A coloured rough metal keeps F_avg-weighted energy: the albedo of each channel lies
// between its single-scattering albedo and its reflectance... and the compensation makes it
// at least the single-scattering value (never darker than before).
TEST(ConductorEnergy, CompensationOnlyAdds) {
    const Color gold(1.f, 0.78f, 0.34f);
    ConductorBSDF metal(gold, gold, 1.f);
    MicrofacetReflection single{TrowbridgeReitz(1.f), gold, gold};
    for (float ct : kViewCos) {
        Color ss = single.SingleAlbedo(ct), total = single.Albedo(ct);
        for (int c = 0; c < 3; ++c) {
            EXPECT_GE(total[c], ss[c]);
            EXPECT_LE(total[c], gold[c] + 1e-4f);
            Estimate e = Albedo(metal, Dir(ct, 0.3f), c);
            EXPECT_NEAR(e.mean, total[c], 4 * e.se + 2e-3) << ct << " channel " << c;
        }
    }
}
