// The GGX albedo tables (ggx_albedo.h) against the C++ lobe they tabulate
// (MicrofacetReflection), and their averages against their own interpolant. Each
// statistical check states the smallest error it detects and proves it with a negative
// control.
#include <gtest/gtest.h>

#include <cmath>

#include "bsdf_checks.h"
#include "ggx_albedo.h"
#include "microfacet.h"
#include "microfacet_reflection.h"

using namespace tessera;
using namespace tessera::testing;

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
