// Tests of what the BSDF kinds share: the kinds list and its dispatch, the factory that
// makes a BSDF from a UsdPreviewSurface (the glass rule, the eta² rule of transmission,
// sanitising) and the power of the chi-square machinery. Each kind's own tests are its
// <kind>_bsdf_test.cpp (docs/materials.md lists them).
#include <gtest/gtest.h>

#include <cmath>
#include <optional>
#include <vector>

#include "bsdf.h"
#include "bsdf_checks.h"

using namespace tessera;
using namespace tessera::testing;

// The kinds list: one name per kind, distinct, in kind order, and the BSDF dispatches to
// the kind it holds.
TEST(BsdfKinds, NamesComeFromTheList) {
    const std::vector<const char*> names = BSDFKindNames();
    ASSERT_EQ(names.size(), BSDFKinds::kCount);
    for (size_t i = 0; i < names.size(); ++i)
        for (size_t j = 0; j < i; ++j) EXPECT_STRNE(names[i], names[j]);
    EXPECT_STREQ(names[kBSDFKindOf<DiffuseBSDF>], "diffuse");
    EXPECT_STREQ(names[kBSDFKindOf<PreviewSurfaceBSDF>], "preview_surface");
    EXPECT_STREQ(BSDF().KindName(), "diffuse");
    const BSDF glass = DielectricBSDF(1.5f, 0.f, TransportMode::Radiance);
    EXPECT_STREQ(glass.KindName(), "dielectric");
    ASSERT_TRUE(glass.GetIf<DielectricBSDF>());
    EXPECT_FALSE(glass.GetIf<ConductorBSDF>());
    // The dispatch reaches the held kind: a smooth interface is a delta, a black Lambertian scatters nothing.
    EXPECT_TRUE(glass.HasDelta() && glass.HasTransmission());
    EXPECT_EQ(BSDF().Flags(), uint32_t(kBSDFUnset));
}

TEST(BsdfFactory, FactoryAppliesTheGlassRule) {
    MaterialParams p;
    EXPECT_TRUE(MakePreviewSurfaceBSDF(p, TransportMode::Radiance).GetIf<PreviewSurfaceBSDF>() != nullptr);
    p.opacity = 0.f;  // clear glass
    BSDF glass = MakePreviewSurfaceBSDF(p, TransportMode::Radiance);
    ASSERT_TRUE(glass.GetIf<DielectricBSDF>());
    EXPECT_EQ(glass.GetIf<DielectricBSDF>()->eta(), 1.5f);
    EXPECT_TRUE(glass.HasTransmission());
    EXPECT_TRUE(glass.IsGlossy());  // roughness 0.5 by default
    p.ior = 1.f;  // index-matched: an invisible surface (presence 0)
    BSDF invisible = MakePreviewSurfaceBSDF(p, TransportMode::Radiance);
    auto bs = invisible.Sample_f(Dir(0.4f, 1.f), 0.3f, {0.2f, 0.7f});
    ASSERT_TRUE(bs);
    EXPECT_TRUE(bs->is_specular && bs->is_transmission);
    EXPECT_NEAR(bs->wi.x, -Dir(0.4f, 1.f).x, 1e-6f);
    EXPECT_NEAR(bs->f.x * std::abs(bs->wi.z) / bs->pdf, 1.f, 1e-6f);
    EXPECT_FALSE(invisible.IsNonSpecular());
    // Cutout mode ignores opacity in the BSDF: the surface is either absent or opaque.
    p.opacity = 0.2f;
    p.opacity_threshold = 0.5f;
    EXPECT_TRUE(IsCutout(p, 0.2f));
    EXPECT_FALSE(IsCutout(p, 0.5f));
    EXPECT_FALSE(MakePreviewSurfaceBSDF(p, TransportMode::Radiance).HasTransmission());
    p.opacity_threshold = 0.f;
    EXPECT_FALSE(IsCutout(p, 0.f));
    EXPECT_TRUE(MakePreviewSurfaceBSDF(p, TransportMode::Radiance).HasTransmission());  // partial: blend
    // A pure metal is a conductor with F0 = F90 = diffuseColor.
    MaterialParams metal;
    metal.metallic = 1.f;
    EXPECT_TRUE(MakePreviewSurfaceBSDF(metal, TransportMode::Radiance).GetIf<ConductorBSDF>() != nullptr);
}

TEST(BsdfFactory, TransmissionObeysEtaSquaredRule) {
    // Veach §5.2, for radiance BSDFs: f(wo, wi) n_i² == f(wi, wo) n_o², with n the index on
    // each direction's side (here n_o = 1 outside, n_i = ior inside). The importance BSDF
    // is the radiance BSDF's adjoint: f_imp(wo, wi) == f_rad(wi, wo).
    int nonzero = 0, asymmetric = 0;
    for (float ior : {1.33f, 1.5f, 2.4f})
        for (float r : {0.05f, 0.3f, 1.f})
            for (float opacity : {0.f, 0.4f}) {
                MaterialParams p = Preview(r, 0.f, ior, 0.f, false, opacity);
                BSDF rad = MakePreviewSurfaceBSDF(p, TransportMode::Radiance);
                BSDF imp = MakePreviewSurfaceBSDF(p, TransportMode::Importance);
                for (int i = 0; i < 3000; ++i) {
                    PixelSampler s(10, uint64_t(i), 0);
                    Vec3 wo = Dir(std::max(1e-3f, s.Get1D()), 2.f * kPi * s.Get1D());        // outside, n = 1
                    Vec3 wi = Dir(-std::max(1e-3f, s.Get1D()), 2.f * kPi * s.Get1D());       // inside, n = ior
                    float a = rad.f(wo, wi).x, b = rad.f(wi, wo).x;
                    if (a > 0.f) ++nonzero;
                    if (std::abs(a - b) > 0.1f * std::max(a, b)) ++asymmetric;
                    ASSERT_NEAR(a * ior * ior, b, 1e-3f * std::max(1.f, b)) << "ior " << ior << " r " << r;
                    ASSERT_NEAR(imp.f(wo, wi).x, b, 1e-3f * std::max(1.f, b));
                    ASSERT_NEAR(imp.f(wi, wo).x, a, 1e-3f * std::max(1.f, a));
                }
            }
    EXPECT_GT(nonzero, 1000);  // the rule was exercised, not satisfied by zeros
    // Negative control: plain symmetry, the rule for reflection, must NOT hold here, so the
    // check above is sensitive to the eta² factor it claims to verify.
    EXPECT_GT(asymmetric, 1000);
}

// Degenerate inputs are sanitised by the factory rather than propagated.
TEST(BsdfFactory, SanitisesDegenerateInputs) {
    MaterialParams bad;
    bad.roughness = NAN;
    bad.ior = -1.f;
    bad.metallic = 2.f;
    bad.diffuse_color = Color(INFINITY, -1.f, 0.5f);
    bad.opacity = 0.5f;
    ExpectFiniteAtExtremes({{"sanitised", MakePreviewSurfaceBSDF(bad, TransportMode::Radiance)}});
}

TEST(BsdfChecks, ChiSquareSeesShape) {
    // Negative controls: the same machinery must reject a pdf 10% too high, and a pdf of
    // the right total but the wrong shape (alpha 20% off, or a lambertian lobe mistaken
    // for a uniform one).
    ConductorBSDF rough(Color(1.f), Color(1.f), 0.3f);
    PreviewSurfaceBSDF preview(Preview(0.3f, 0.f, 1.5f, 1.f), TransportMode::Radiance);
    DielectricBSDF glass(1.5f, 0.3f, TransportMode::Radiance);
    for (const BSDF& b : {BSDF(rough), BSDF(preview), BSDF(glass)}) {
        EXPECT_FALSE(BSDFChiSquare(b, Dir(0.6f, 0.3f), 7, 1.1).pass);
        EXPECT_TRUE(BSDFChiSquare(b, Dir(0.6f, 0.3f), 7, 1.0).pass);
    }
    ConductorBSDF wider(Color(1.f), Color(1.f), 0.36f);
    Vec3 wo = Dir(0.6f, 0.3f);
    auto wrong_shape = DirectionsChiSquare(
        [&](PixelSampler& s) -> std::optional<Vec3> {
            float uc = s.Get1D();
            auto bs = rough.Sample_f(wo, uc, s.Get2D());
            return bs ? std::optional<Vec3>(bs->wi) : std::nullopt;
        },
        [&](Vec3 wi) { return double(wider.PDF(wo, wi)); }, PeakHints(wo), 8);
    EXPECT_FALSE(wrong_shape.pass) << wrong_shape.statistic;
    DiffuseBSDF lambert(Color(1.f));
    auto uniform = DirectionsChiSquare(
        [&](PixelSampler& s) -> std::optional<Vec3> {
            float uc = s.Get1D();
            return lambert.Sample_f(wo, uc, s.Get2D())->wi;
        },
        [&](Vec3 wi) { return wi.z > 0.f ? double(kInv2Pi) : 0.0; }, PeakHints(wo), 9);
    EXPECT_FALSE(uniform.pass) << uniform.statistic;
}
