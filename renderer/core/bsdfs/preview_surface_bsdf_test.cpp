// PreviewSurfaceBSDF: the properties every kind has (bsdf_checks.h), on the parameter sets
// of roughness 0.05/0.3/1 (and 0 = delta), metallic 0/1, ior 1/1.5, clearcoat on/off, the
// specular workflow and glass blends, each also with its table attached; then the
// workflows' Fresnel, the table, the exact-Lambertian rule and the energy of the layering.
// Each statistical check states the smallest error it detects and has a negative control.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <deque>
#include <string>
#include <vector>

#include "bsdf_checks.h"
#include "conductor_bsdf.h"
#include "diffuse_bsdf.h"
#include "fresnel.h"
#include "preview_surface_bsdf.h"

using namespace tessera;
using namespace tessera::testing;

namespace {

// Tables live as long as the test program, like Scene's live as long as the scene.
const PreviewSurfaceTable* KeepTable(const PreviewSurfaceTable& t) {
    static std::deque<PreviewSurfaceTable> kept;
    kept.push_back(t);
    return &kept.back();
}

std::vector<NamedBSDF> PreviewSurfaceCases(TransportMode mode, bool white) {
    std::vector<NamedBSDF> v;
    const Color tint = white ? Color(1.f) : Color(0.8f, 0.5f, 0.2f);
    for (float r : {0.f, 0.05f, 0.3f, 1.f})
        for (float m : {0.f, 1.f})
            for (float cc : {0.f, 1.f})
                for (float ior : {1.f, 1.5f}) {
                    MaterialParams p = Preview(r, m, ior, cc, false, 1.f, tint);
                    v.push_back({"preview r=" + std::to_string(r) + " metallic=" + std::to_string(m) + " coat=" +
                                     std::to_string(cc) + " ior=" + std::to_string(ior),
                                 PreviewSurfaceBSDF(p, mode)});
                }
    for (float r : {0.f, 0.3f}) {
        MaterialParams p = Preview(r, 0.f, 1.5f, 0.5f, true, 1.f, tint);
        if (white) p.specular_color = Color(1.f);
        v.push_back({"preview specular workflow r=" + std::to_string(r), PreviewSurfaceBSDF(p, mode)});
        MaterialParams smooth_coat = Preview(r, 0.5f, 1.5f, 1.f, false, 1.f, tint);
        smooth_coat.clearcoat_roughness = 0.f;
        v.push_back({"preview smooth coat metallic=0.5 r=" + std::to_string(r), PreviewSurfaceBSDF(smooth_coat, mode)});
    }
    for (float r : {0.f, 0.3f, 1.f})
        for (float ior : {1.f, 1.5f})
            v.push_back({"preview opacity=0.4 ior=" + std::to_string(ior) + " r=" + std::to_string(r),
                         PreviewSurfaceBSDF(Preview(r, 0.f, ior, 0.f, false, 0.4f, tint), mode)});
    // Every case again with its table attached, as Scene builds untextured materials.
    const size_t n = v.size();
    for (size_t i = 0; i < n; ++i) {
        PreviewSurfaceBSDF tabulated = *v[i].bsdf.GetIf<PreviewSurfaceBSDF>();
        tabulated.UseTable(KeepTable(tabulated.Tabulate()));
        v.push_back({v[i].name + " tabulated", tabulated, v[i].lossless});
    }
    return v;
}

MaterialParams Plastic(float roughness, float ior, Color diffuse) {
    MaterialParams p;
    p.diffuse_color = diffuse;
    p.roughness = roughness;
    p.metallic = 0.f;
    p.ior = ior;
    return p;
}

}  // namespace

TEST(PreviewSurfaceBSDF, SamplingFollowsPdf) { ExpectSamplingFollowsPdf(PreviewSurfaceCases, 5000); }
TEST(PreviewSurfaceBSDF, WhiteFurnaceAtMostOne) { ExpectWhiteFurnaceAtMostOne(PreviewSurfaceCases); }
TEST(PreviewSurfaceBSDF, SampleAgreesReciprocalAndFinite) { ExpectConsistentReciprocalAndFinite(PreviewSurfaceCases); }

TEST(PreviewSurfaceBSDF, LayeringKeepsMostEnergy) {
    // The rule must not merely bound energy but keep most of it: smooth white plastic with
    // a smooth coat reflects about Fc + (1 - Fc)(Fs + (1 - Fs)(1 - F_avg)) at normal
    // incidence, above 0.85 (a rule that attenuated the base twice as hard drops below).
    MaterialParams p = Preview(0.f, 0.f, 1.5f, 1.f, false, 1.f, Color(1.f));
    p.clearcoat_roughness = 0.f;
    Furnace fu = WhiteFurnace(PreviewSurfaceBSDF(p, TransportMode::Radiance), Dir(1.f, 0.f), TransportMode::Radiance);
    EXPECT_GT(fu.mean.x, 0.85f);
    EXPECT_LE(fu.mean.x, 1.f + 5.f * fu.stderr_.x);
}

TEST(PreviewSurfaceBSDF, FresnelFollowsTheWorkflow) {
    // Smooth surfaces with a black base: the mirror sample's weight is the Fresnel term.
    auto mirror_weight = [](const MaterialParams& p, float ct) {
        PreviewSurfaceBSDF b(p, TransportMode::Radiance);
        Color total(0.f);
        // Sum over lobe choices: weights are f |cos| / pdf of each delta lobe times its pdf.
        for (float uc = 0.0005f; uc < 1.f; uc += 0.001f) {
            auto bs = b.Sample_f(Dir(ct, 0.f), uc, {0.5f, 0.5f});
            if (bs && bs->is_specular) total += bs->f * (std::abs(bs->wi.z) / bs->pdf) * 0.001f;
        }
        return total;
    };
    MaterialParams p;
    p.roughness = 0.f;
    p.diffuse_color = Color(0.f);
    p.ior = 1.5f;
    EXPECT_NEAR(mirror_weight(p, 1.f).x, 0.04f, 1e-3f);                                  // F0 from ior
    EXPECT_NEAR(mirror_weight(p, 0.02f).x, FrSchlick(0.04f, 1.f, 0.02f), 2e-3f);         // F90 = 1
    p.ior = 1.f;
    EXPECT_NEAR(mirror_weight(p, 1.f).x, 0.f, 1e-6f);
    // ior 1 is no interface: the exact Fresnel is 0 at every angle, and F90 = min(1, 50 F0)
    // follows it (Storm's F90 = 1 would reflect 0.9 here).
    EXPECT_NEAR(mirror_weight(p, 0.02f).x, 0.f, 1e-6f);
    p.ior = 1.2f;  // F0 = 0.0083: F90 = 0.41
    EXPECT_NEAR(mirror_weight(p, 0.02f).x, FrSchlick(F0FromIor(1.2f), 50.f * F0FromIor(1.2f), 0.02f), 2e-3f);
    p.metallic = 1.f;
    p.diffuse_color = Color(0.9f, 0.5f, 0.1f);
    p.clearcoat = 1e-6f;  // keep it a PreviewSurfaceBSDF, not the factory's conductor shortcut
    for (float ct : {1.f, 0.3f, 0.02f}) {
        Color w = mirror_weight(p, ct);
        EXPECT_NEAR(w.x, 0.9f, 2e-3f);  // F0 = F90 = diffuseColor
        EXPECT_NEAR(w.z, 0.1f, 2e-3f);
    }
    MaterialParams s;
    s.roughness = 0.f;
    s.diffuse_color = Color(0.f);
    s.use_specular_workflow = true;
    s.specular_color = Color(0.2f, 0.4f, 0.6f);
    s.ior = 1.f;  // ignored by the specular workflow
    Color w = mirror_weight(s, 1.f);
    EXPECT_NEAR(w.x, 0.2f, 1e-3f);
    EXPECT_NEAR(w.z, 0.6f, 1e-3f);
}

TEST(PreviewSurfaceBSDF, PureMetalMatchesConductor) {
    // The mixture with metallic = 1 and no coat is exactly the conductor.
    for (float r : {0.05f, 0.3f, 1.f}) {
        MaterialParams p = Preview(r, 1.f, 1.5f, 0.f);
        PreviewSurfaceBSDF mix(p, TransportMode::Radiance);
        ConductorBSDF cond(p.diffuse_color, p.diffuse_color, TrowbridgeReitz::RoughnessToAlpha(r));
        for (int i = 0; i < 500; ++i) {
            PixelSampler s(12, uint64_t(i), 0);
            Vec3 wo = Dir(std::max(1e-3f, s.Get1D()), 0.f), wi = Dir(std::max(1e-3f, s.Get1D()), 2.f * kPi * s.Get1D());
            Color a = mix.f(wo, wi), b = cond.f(wo, wi);
            ASSERT_NEAR(a.x, b.x, 1e-4f * std::max(1.f, b.x));
            ASSERT_NEAR(mix.PDF(wo, wi), cond.PDF(wo, wi), 1e-3f * std::max(1.f, cond.PDF(wo, wi)));
        }
    }
}

// specularColor 0 (specular workflow) or ior 1 with metallic 0 leave no specular Fresnel at
// any angle: the mixture is then exactly a Lambertian of diffuseColor (Scene renders it as
// one). Bit for bit in f, PDF and Sample_f, for rough and smooth settings and wo on either
// side; any real lobe (a faint specular colour, ior 1.5, a coat, partial opacity) is not.
TEST(PreviewSurfaceBSDF, ExactlyLambertianWhenTheFresnelVanishes) {
    const Color rho(0.8f, 0.5f, 0.2f);
    auto exported = [&](float roughness) {
        MaterialParams p;
        p.diffuse_color = rho;
        p.roughness = roughness;
        p.use_specular_workflow = true;
        p.specular_color = Color(0.f);
        return p;
    };
    MaterialParams ior1;
    ior1.diffuse_color = rho;
    ior1.ior = 1.f;
    const DiffuseBSDF lambert(rho);
    for (const MaterialParams& p : {exported(1.f), exported(0.3f), exported(0.f), ior1}) {
        const std::optional<Color> albedo = ExactLambertianAlbedo(p);
        ASSERT_TRUE(albedo);
        ASSERT_EQ(albedo->x, rho.x);
        ASSERT_EQ(albedo->z, rho.z);
        const PreviewSurfaceBSDF mix(p, TransportMode::Radiance);
        for (int i = 0; i < 2000; ++i) {
            PixelSampler s(5, uint64_t(i), 0);
            const float side = i % 2 ? 1.f : -1.f;
            Vec3 wo = Dir(side * std::max(1e-3f, s.Get1D()), 2.f * kPi * s.Get1D());
            Vec3 wi = Dir((i % 3 ? 1.f : -1.f) * std::max(1e-3f, s.Get1D()), 2.f * kPi * s.Get1D());
            const Color a = mix.f(wo, wi), b = lambert.f(wo, wi);
            ASSERT_TRUE(a.x == b.x && a.y == b.y && a.z == b.z) << Str(wo) << Str(wi);
            ASSERT_EQ(mix.PDF(wo, wi), lambert.PDF(wo, wi));
            const float uc = s.Get1D();
            const Vec2 u = s.Get2D();
            auto sa = mix.Sample_f(wo, uc, u), sb = lambert.Sample_f(wo, uc, u);
            ASSERT_EQ(bool(sa), bool(sb));
            if (!sa) continue;
            ASSERT_TRUE(sa->wi.x == sb->wi.x && sa->wi.y == sb->wi.y && sa->wi.z == sb->wi.z);
            ASSERT_EQ(sa->pdf, sb->pdf);
            ASSERT_EQ(sa->f.y, sb->f.y);
            ASSERT_FALSE(sa->is_specular || sa->is_transmission);
        }
    }
    // Controls: each of these is a different surface, and the rule must say so.
    MaterialParams faint = exported(1.f);
    faint.specular_color = Color(1e-3f, 0.f, 0.f);
    MaterialParams default_ior = ior1;
    default_ior.ior = 1.5f;
    MaterialParams coat = exported(1.f);
    coat.clearcoat = 0.1f;
    MaterialParams see_through = exported(1.f);
    see_through.opacity = 0.99f;
    MaterialParams cutout = exported(1.f);
    cutout.opacity = 0.4f;
    cutout.opacity_threshold = 0.5f;
    MaterialParams metal = ior1;
    metal.metallic = 0.01f;
    for (const MaterialParams& p : {faint, default_ior, coat, see_through, cutout, metal})
        EXPECT_FALSE(ExactLambertianAlbedo(p));
    // The faintest of them is measurably not Lambertian at grazing angles.
    const PreviewSurfaceBSDF faint_mix(faint, TransportMode::Radiance);
    const Vec3 wo = Dir(0.05f, 0.f), wi = Dir(0.05f, kPi);
    EXPECT_NE(faint_mix.f(wo, wi).x, lambert.f(wo, wi).x);
    // A cutout whose opacity clears its threshold is opaque everywhere: still Lambertian.
    cutout.opacity = 0.6f;
    EXPECT_TRUE(ExactLambertianAlbedo(cutout));
}

// The table reproduces what it tabulates: f within 2e-5 relative of the direct evaluation
// (its terms are the GGX tables' own interpolant, up to rounding) and lobe probabilities
// within 0.01 (an interpolant of the exact ones; the chi-square and consistency tests above
// check that sampling follows the tabulated pdf). The control: the table of a surface of
// roughness 0.8 instead of 1 differs in f by more than 20 times that tolerance.
TEST(PreviewSurfaceBSDF, TableReproducesTheDirectEvaluation) {
    for (const MaterialParams& p : {Preview(1.f, 0.f, 1.5f, 0.f), Preview(0.3f, 0.f, 1.5f, 1.f),
                                    Preview(0.5f, 0.5f, 2.4f, 0.f, true), Preview(0.3f, 0.f, 1.5f, 0.f, false, 0.4f)}) {
        const PreviewSurfaceBSDF direct(p, TransportMode::Radiance);
        PreviewSurfaceBSDF tabulated = direct;
        tabulated.UseTable(KeepTable(direct.Tabulate()));
        MaterialParams rougher = p;
        rougher.roughness = p.roughness == 1.f ? 0.8f : std::min(1.f, p.roughness + 0.2f);
        PreviewSurfaceBSDF wrong = direct;
        wrong.UseTable(KeepTable(PreviewSurfaceBSDF(rougher, TransportMode::Radiance).Tabulate()));
        double worst = 0.0, worst_wrong = 0.0;
        for (int i = 0; i < 4000; ++i) {
            PixelSampler s(9, uint64_t(i), 0);
            const Vec3 wo = Dir(std::max(1e-3f, s.Get1D()), 0.f), wi = Dir(std::max(1e-3f, s.Get1D()), 2.f * kPi * s.Get1D());
            const Color a = direct.f(wo, wi), b = tabulated.f(wo, wi), c = wrong.f(wo, wi);
            for (int k = 0; k < 3; ++k) {
                const double scale = std::max(1e-3, double(a[k]));
                worst = std::max(worst, std::abs(double(b[k]) - a[k]) / scale);
                worst_wrong = std::max(worst_wrong, std::abs(double(c[k]) - a[k]) / scale);
            }
            // The pdf of the same wi through each: equal up to the probabilities' lerp.
            const float pd = direct.PDF(wo, wi), pt = tabulated.PDF(wo, wi);
            ASSERT_NEAR(pt, pd, 0.01f * std::max(1.f, pd)) << Str(wo) << Str(wi);
        }
        EXPECT_LT(worst, 2e-5) << "roughness " << p.roughness;
        EXPECT_GT(worst_wrong, 4e-4) << "roughness " << p.roughness;
    }
}

// --- energy (docs/materials.md, "Energy conservation") ---------------------------------

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
