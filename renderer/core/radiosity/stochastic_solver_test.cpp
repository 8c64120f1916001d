// The stochastic solver against the closed furnace box and against the progressive
// solver (form factors computed analytically, no rays but the visibility ones) on the room
// with a blocker; and its determinism across thread counts.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstring>

#include "radiosity_scenes.h"
#include "scene_helpers.h"
#include "stochastic_solver.h"

namespace {

using namespace tessera;
using namespace tessera_test;

constexpr float kPi = 3.14159265358979323846f;

// A closed box of albedo rho whose every wall emits: B = E / (1 - rho) everywhere. Every ray
// of a closed box lands, and each carries the same power, so the area-weighted mean of B
// is exact up to the tolerance and the ambient term; single elements carry the rays' noise.
struct BoxResult {
    double mean_error;  // area-weighted mean B over the closed form, minus 1
    double rms_error;   // root mean square of the per-element relative errors
};
BoxResult Box(float rho, float rho_expected, uint32_t seed) {
    FurnaceBox box(rho, 0.3f);
    box.settings.seed = seed;
    const RadiositySolution sol = SolveStochastic(box.scene, box.mesh, box.settings);
    EXPECT_TRUE(sol.converged);
    const std::vector<Color> reflected = ReflectedRadiosity(box.mesh, sol);
    const double want = kPi * FurnaceBox::kLe / (1.0 - rho_expected);
    double sum = 0.0, area = 0.0, sq = 0.0;
    const auto& el = box.mesh.elements();
    for (size_t e = 0; e < el.size(); ++e) {
        const double b = box.B(reflected, e);
        sum += b * el[e].area;
        area += el[e].area;
        sq += (b / want - 1.0) * (b / want - 1.0);
    }
    return {sum / area / want - 1.0, std::sqrt(sq / double(el.size()))};
}

// Measured (rho 0.3 / 0.5 / 0.8): mean errors below 1e-4, per-element rms 0.3 / 0.5 / 0.8 %.
// The mean's 0.2 % bound detects a 2 % error (the control's albedo moves the closed form 2 %).
TEST(StochasticRadiosity, ClosedBoxGivesEOverOneMinusRho) {
    for (float rho : {0.3f, 0.5f, 0.8f}) {
        const BoxResult r = Box(rho, rho, 1);
        std::printf("rho %.1f: mean %+.5f, rms %.4f\n", rho, r.mean_error, r.rms_error);
        EXPECT_LT(std::abs(r.mean_error), 0.002) << "rho " << rho;
        EXPECT_LT(r.rms_error, 0.02) << "rho " << rho;
        const float other = 1.f - (1.f - rho) * 1.02f;
        EXPECT_GT(std::abs(Box(rho, other, 1).mean_error), 0.002) << "rho " << rho;
    }
}

// The direct radiosity of the room's floor, summed over its elements (W), computed here
// without the renderer: the light (Le 10, facing down, [0.8, 1.2]^2 at y = 1.99) seen from
// 64 points of each floor element by a 32 x 32 midpoint rule, visibility against the
// blocker ([0.5, 1.5]^2 at y = 1) by hand. The floor is lit only near the walls, in the
// blocker's penumbra: the hard case for a form-factor estimator's few visibility rays.
double FloorDirectReference(const RadiosityMesh& mesh) {
    constexpr float kLe = 10.f, kRho = 0.5f;  // the green channel
    constexpr int kLight = 32, kPoints = 8;
    double total = 0.0;
    for (const RadiosityElement& e : mesh.elements()) {
        if (!(e.n.y > 0.9f && e.center.y < 0.01f)) continue;
        double irradiance = 0.0;
        for (int i = 0; i < kPoints; ++i)
            for (int j = 0; j < kPoints; ++j) {
                const float u = (i + 0.5f) / kPoints, v = (j + 0.5f) / kPoints;
                const float su = std::sqrt(u);  // uniform on the triangle
                const Vec3 x = e.p[0] * (1.f - su) + e.p[1] * (su * (1.f - v)) + e.p[2] * (su * v);
                double sum = 0.0;
                for (int a = 0; a < kLight; ++a)
                    for (int b = 0; b < kLight; ++b) {
                        const Vec3 l(0.8f + 0.4f * (a + 0.5f) / kLight, 1.99f, 0.8f + 0.4f * (b + 0.5f) / kLight);
                        const float t = (1.f - x.y) / (l.y - x.y);  // where the segment crosses y = 1
                        const float cx = x.x + t * (l.x - x.x), cz = x.z + t * (l.z - x.z);
                        if (cx > 0.5f && cx < 1.5f && cz > 0.5f && cz < 1.5f) continue;
                        const Vec3 d = l - x;
                        const float r2 = Dot(d, d);
                        sum += double(d.y) * double(d.y) / (double(r2) * r2);  // cos cos' / r^2
                    }
                irradiance += sum * (0.16 / (kLight * kLight));
            }
        total += kRho * kLe * irradiance / (kPoints * kPoints) * e.area;
    }
    return total;
}

double FloorDirect(const RadiosityMesh& mesh, const RadiositySolution& sol) {
    double total = 0.0;
    for (size_t e = 0; e < mesh.elements().size(); ++e) {
        const RadiosityElement& x = mesh.elements()[e];
        if (x.n.y > 0.9f && x.center.y < 0.01f) total += sol.direct[2 * e].y * x.area;
    }
    return total;
}

// Per wall of the room, against the progressive solver at tolerance 1e-4, and the floor's
// direct light against the reference above. What separates the solvers: the stochastic
// one's noise (the spread between two seeds shows it) and the progressive one's estimator,
// whose 4 visibility rays per element pair see the floor's penumbra too dark. Measured:
// walls within 0.5 % of progressive but the floor +3.3 %; the floor's direct part is
// within 0.6 % of the reference for the stochastic solver (two seeds) and 18 % under it
// for the progressive one (which is the control: the 2 % bound must refuse it).
TEST(StochasticRadiosity, AgreesWithProgressivePerWallAndWithTheFloorsPenumbra) {
    const RadiosityRoom& room = RadiosityRoom::Get();
    const RadiositySolution p = SolveProgressive(room.scene, room.mesh, RadiosityRoom::Settings(1e-4f));
    RadiositySettings s = RadiosityRoom::Settings(1e-4f);
    const RadiositySolution a = SolveStochastic(room.scene, room.mesh, s);
    s.seed = 7;
    const RadiositySolution b = SolveStochastic(room.scene, room.mesh, s);
    const std::vector<double> ea = room.WallErrors(p, a), eb = room.WallErrors(p, b);
    std::printf("%llu rays, %u iterations\n", (unsigned long long)a.rays, a.shots);
    constexpr int kFloor = 3;
    for (int w = 0; w < 6; ++w) {
        std::printf("wall %d: %+.4f (seed 0), %+.4f (seed 7)\n", w, ea[w], eb[w]);
        if (w == kFloor) continue;
        EXPECT_LT(std::abs(ea[w]), 0.01) << w;
        EXPECT_LT(std::abs(eb[w]), 0.01) << w;
    }
    EXPECT_TRUE(a.converged);
    const double ref = FloorDirectReference(room.mesh);
    const double da = FloorDirect(room.mesh, a) / ref - 1.0, db = FloorDirect(room.mesh, b) / ref - 1.0;
    const double dp = FloorDirect(room.mesh, p) / ref - 1.0;
    std::printf("floor direct against the reference: %+.4f (seed 0), %+.4f (seed 7), progressive %+.4f\n", da, db,
                dp);
    EXPECT_LT(std::abs(da), 0.02);
    EXPECT_LT(std::abs(db), 0.02);
    EXPECT_GE(std::abs(dp), 0.02);
    // Negative control of the wall bound: the stochastic solution 2 % brighter fails it.
    int failing = 0;
    for (double e : ea) failing += std::abs((1.0 + e) * 1.02 - 1.0) >= 0.01;
    EXPECT_EQ(failing, 6);
}

TEST(StochasticRadiosity, SameBitsForAnyThreadCount) {
    const RadiosityRoom& room = RadiosityRoom::Get();
    RadiositySettings s = RadiosityRoom::Settings(1e-3f);
    s.rays_per_element = 64.f;
    s.threads = 1;
    const RadiositySolution one = SolveStochastic(room.scene, room.mesh, s);
    s.threads = 2;
    const RadiositySolution two = SolveStochastic(room.scene, room.mesh, s);
    ASSERT_EQ(one.radiosity.size(), two.radiosity.size());
    EXPECT_EQ(std::memcmp(one.radiosity.data(), two.radiosity.data(), one.radiosity.size() * sizeof(Color)), 0);
    EXPECT_EQ(std::memcmp(one.direct.data(), two.direct.data(), one.direct.size() * sizeof(Color)), 0);
    EXPECT_EQ(one.rays, two.rays);
    // Control: another seed gives other bits.
    s.seed = 3;
    const RadiositySolution other = SolveStochastic(room.scene, room.mesh, s);
    EXPECT_NE(std::memcmp(one.radiosity.data(), other.radiosity.data(), one.radiosity.size() * sizeof(Color)), 0);
}

}  // namespace
