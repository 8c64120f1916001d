#include <gtest/gtest.h>

#include <cmath>

#include "bvh_light_sampler.h"
#include "chi_square.h"
#include "sampler.h"

using namespace tessera;

namespace {

struct Tri {
    Vec3 p[3];
    bool two_sided;
};

LightBounds BoundsOf(const Tri& t, float phi) { return LightBounds::Triangle(t.p, phi, t.two_sided); }

// 300 small triangles scattered in a 10-unit cube, random orientations, a third two-sided.
struct Field {
    std::vector<Tri> tris;
    std::vector<LightBounds> bounds;
    std::vector<uint32_t> ids;
    BVHLightSampler bvh;
    Field() {
        PixelSampler s(11, 0, 0);
        for (uint32_t i = 0; i < 300; ++i) {
            const Vec3 c(10.f * s.Get1D(), 10.f * s.Get1D(), 10.f * s.Get1D());
            Tri t;
            for (int k = 0; k < 3; ++k)
                t.p[k] = c + Vec3(s.Get1D() - 0.5f, s.Get1D() - 0.5f, s.Get1D() - 0.5f) * 0.4f;
            t.two_sided = i % 3 == 0;
            tris.push_back(t);
            bounds.push_back(BoundsOf(t, 0.5f + 2.f * s.Get1D()));
            ids.push_back(i + 5);  // emitter ids need not start at 0 (area lights follow others)
        }
        bvh = BVHLightSampler(bounds, ids, 305);
    }
};

// Whether triangle t can send light to p at all: p in front of its plane (either side when
// two-sided). This is what the sampler must never rule out.
bool CanLight(const Tri& t, Vec3 p) {
    const Vec3 n = Cross(t.p[1] - t.p[0], t.p[2] - t.p[0]);
    const float side = Dot(p - t.p[0], n);
    return t.two_sided ? side != 0.f : side > 0.f;
}

}  // namespace

// The pmfs at a point sum to at most 1: a node's bound can reach p where none of its
// emitters does, and a sample that goes there finds no light (Sample returns false).
TEST(BVHLightSampler, PmfsSumToAtMostOneAndAreZeroOnlyWhereNoLightCanReach) {
    Field f;
    PixelSampler s(3, 0, 0);
    for (int q = 0; q < 200; ++q) {
        const Vec3 p(12.f * s.Get1D() - 1.f, 12.f * s.Get1D() - 1.f, 12.f * s.Get1D() - 1.f);
        const Vec3 n = q % 4 == 0 ? Vec3(0.f) : Normalize(Vec3(s.Get1D() - 0.5f, s.Get1D() - 0.5f, s.Get1D() - 0.5f));
        double sum = 0.0;
        for (size_t i = 0; i < f.tris.size(); ++i) {
            const float pmf = f.bvh.Pmf(p, n, f.ids[i]);
            sum += pmf;
            if (CanLight(f.tris[i], p)) ASSERT_GT(pmf, 0.f) << "triangle " << i << " can light the point but has pmf 0";
        }
        EXPECT_LE(sum, 1.0 + 1e-5) << "point " << q;
        EXPECT_GT(sum, 0.5) << "point " << q << ": most of the mass is lost in dead ends";
        EXPECT_EQ(f.bvh.Pmf(p, n, 0), 0.f);    // ids not in the tree
        EXPECT_EQ(f.bvh.Pmf(p, n, 999), 0.f);
    }
}

TEST(BVHLightSampler, SamplesFollowThePmfAndReportIt) {
    Field f;
    const Vec3 p(5.f, 5.f, 5.f), n = Normalize(Vec3(0.3f, 1.f, -0.2f));
    const int count = 400000;
    // One bin per light and a last one for samples that found none.
    std::vector<double> observed(f.tris.size() + 1, 0.0), expected(f.tris.size() + 1);
    double total = 0.0;
    for (size_t i = 0; i < f.tris.size(); ++i) total += expected[i] = count * double(f.bvh.Pmf(p, n, f.ids[i]));
    expected.back() = std::max(0.0, count - total);
    for (int k = 0; k < count; ++k) {
        PixelSampler s(4, uint64_t(k), 0);
        uint32_t e = 0;
        float pmf = 0.f;
        if (!f.bvh.Sample(s.Get1D(), p, n, &e, &pmf)) {
            ASSERT_EQ(pmf, 0.f);
            observed.back() += 1.0;
            continue;
        }
        ASSERT_GE(e, 5u);
        ASSERT_LT(e, 305u);
        ASSERT_EQ(pmf, f.bvh.Pmf(p, n, e)) << "Sample and Pmf disagree for emitter " << e;
        observed[e - 5] += 1.0;
    }
    auto r = tessera::testing::ChiSquareTest(observed, expected);
    EXPECT_TRUE(r.pass) << "chi2 " << r.statistic << " dof " << r.dof;
    // Control: the same counts fail against a pmf with 5 % moved from one half of the lights
    // to the other (chi-square excess ~ 0.05^2 x 400k = 1000 against a critical margin ~120).
    std::vector<double> skewed(expected);
    for (size_t i = 0; i + 1 < skewed.size(); ++i) skewed[i] *= i < skewed.size() / 2 ? 1.05 : 0.95;
    EXPECT_FALSE(tessera::testing::ChiSquareTest(observed, skewed).pass);
}

TEST(BVHLightSampler, NearFacingLightsOutweighFarOrAverted) {
    // Two groups of 8 one-sided triangles: near ones facing p, and the same group mirrored
    // far away. Importance must favour the near group; a group facing away gets nothing.
    std::vector<LightBounds> bounds;
    std::vector<uint32_t> ids;
    for (uint32_t i = 0; i < 16; ++i) {
        const float x = float(i % 8) * 0.1f;
        const float z = i < 8 ? 1.f : 20.f;
        Tri t{{Vec3(x, 0.f, z), Vec3(x + 0.05f, 0.f, z), Vec3(x, 0.05f, z)}, false};  // normal +z
        if (i < 8) std::swap(t.p[1], t.p[2]);  // near group faces -z, toward the origin
        bounds.push_back(BoundsOf(t, 1.f));
        ids.push_back(i);
    }
    BVHLightSampler bvh(bounds, ids, 16);
    const Vec3 p(0.f, 0.f, 0.f), n(0.f, 0.f, 1.f);
    double near = 0.0, far = 0.0;
    for (uint32_t i = 0; i < 16; ++i) (i < 8 ? near : far) += bvh.Pmf(p, n, i);
    EXPECT_NEAR(near, 1.0, 1e-6);
    EXPECT_EQ(far, 0.0) << "the far group faces +z, away from the origin";
    // From beyond the far group (z = 30) both groups face away from... the near one; the far one is lit.
    double far_seen = 0.0;
    for (uint32_t i = 8; i < 16; ++i) far_seen += bvh.Pmf(Vec3(0.f, 0.f, 30.f), Vec3(0.f), i);
    EXPECT_NEAR(far_seen, 1.0, 1e-6);
}

TEST(BVHLightSampler, ConeUnionHoldsBothCones) {
    PixelSampler s(5, 0, 0);
    for (int k = 0; k < 2000; ++k) {
        LightBounds a, b;
        a.phi = b.phi = 1.f;
        a.lo = b.lo = Vec3(0.f);
        a.hi = b.hi = Vec3(1.f);
        a.w = Normalize(Vec3(s.Get1D() - 0.5f, s.Get1D() - 0.5f, s.Get1D() - 0.5f));
        b.w = Normalize(Vec3(s.Get1D() - 0.5f, s.Get1D() - 0.5f, s.Get1D() - 0.5f));
        a.cos_theta_o = std::cos(s.Get1D() * 1.5f);
        b.cos_theta_o = std::cos(s.Get1D() * 1.5f);
        const LightBounds u = LightBounds::Union(a, b);
        // The edge of each cone, in several directions around its axis, is inside the union.
        for (const LightBounds* c : {&a, &b}) {
            const Vec3 t = Normalize(Cross(c->w, std::abs(c->w.x) < 0.9f ? Vec3(1.f, 0.f, 0.f) : Vec3(0.f, 1.f, 0.f)));
            const Vec3 t2 = Cross(c->w, t);
            const float sin_o = std::sqrt(std::max(0.f, 1.f - c->cos_theta_o * c->cos_theta_o));
            for (int j = 0; j < 8; ++j) {
                const float phi = 2.f * kPi * float(j) / 8.f;
                const Vec3 edge = c->w * c->cos_theta_o + (t * std::cos(phi) + t2 * std::sin(phi)) * sin_o;
                ASSERT_GE(Dot(edge, u.w), u.cos_theta_o - 1e-5f) << "cone " << k;
            }
        }
    }
}
