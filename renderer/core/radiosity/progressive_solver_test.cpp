// The progressive solver against closed forms, through the real scene and Embree.
//
// A closed diffuse box of albedo rho whose every wall emits E: every point sees only the
// box, so B = E + rho B, B = E / (1 - rho). The point-to-element factors of a closed
// convex enclosure sum to exactly 1 (they partition the projected hemisphere), so the only
// error is the solver's tolerance (1e-4 of the power, with the ambient term); the check
// allows 0.5 %, and a box of albedo rho' whose closed form is 2 % away must fail it.
#include <gtest/gtest.h>

#include <cmath>

#include "progressive_solver.h"
#include "radiosity_mesh.h"
#include "radiosity_scenes.h"
#include "scene_helpers.h"

namespace {

using namespace tessera;
using namespace tessera_test;

constexpr float kPi = 3.14159265358979323846f;

// Mean relative error of B on the front sides against E / (1 - rho_expected).
double BoxError(float rho, float rho_expected, float tolerance, RadiositySolution* out = nullptr) {
    FurnaceBox box(rho, 0.3f);
    box.settings.tolerance = tolerance;
    const RadiositySolution sol = SolveProgressive(box.scene, box.mesh, box.settings);
    const std::vector<Color> reflected = ReflectedRadiosity(box.mesh, sol);
    const double want = kPi * FurnaceBox::kLe / (1.0 - rho_expected);
    double worst = 0.0;
    for (size_t e = 0; e < box.mesh.elements().size(); ++e) worst = std::max(worst, std::abs(box.B(reflected, e) / want - 1.0));
    if (out) *out = sol;
    return worst;
}

TEST(ProgressiveRadiosity, ClosedBoxGivesEOverOneMinusRho) {
    for (float rho : {0.3f, 0.5f, 0.8f}) {
        RadiositySolution sol;
        const double err = BoxError(rho, rho, 1e-4f, &sol);
        EXPECT_LT(err, 0.005) << "rho " << rho;
        EXPECT_TRUE(sol.converged);
        // Negative control: the closed form of an albedo that moves it by 2 %.
        const float other = 1.f - (1.f - rho) * 1.02f;
        EXPECT_GT(BoxError(rho, other, 1e-4f), 0.005) << "rho " << rho;
    }
}

// Without the ambient term the unconverged part would show: a loose tolerance still
// lands near the closed form because the ambient term stands in for the unshot power.
TEST(ProgressiveRadiosity, AmbientTermCoversTheUnshotPower) {
    EXPECT_LT(BoxError(0.8f, 0.8f, 0.05f), 0.03);
}

// Southwell shooting never increases the unshot power when every reflectance is below 1
// and the factors from an element sum to at most 1: the residual falls monotonically.
TEST(ProgressiveRadiosity, ResidualFallsMonotonically) {
    SceneDesc desc;
    AddInwardBox(desc, {0, 0, 0}, {2, 2, 2}, AddMaterial(desc, Color(0.7f, 0.5f, 0.3f), Color(0.f)));
    const uint32_t light = AddMaterial(desc, Color(0.f), Color(10.f));
    AddQuad(desc, {0.8f, 1.99f, 0.8f}, {1.2f, 1.99f, 0.8f}, {1.2f, 1.99f, 1.2f}, {0.8f, 1.99f, 1.2f}, light);
    // A blocker, so that visibility matters.
    const uint32_t grey = AddMaterial(desc, Color(0.6f), Color(0.f));
    AddQuad(desc, {0.5f, 1.f, 0.5f}, {0.5f, 1.f, 1.5f}, {1.5f, 1.f, 1.5f}, {1.5f, 1.f, 0.5f}, grey);
    const Scene scene(desc);
    const RadiosityMesh mesh(scene, 0.25f);
    RadiositySettings s;
    s.element_size = 0.25f;
    s.tolerance = 1e-3f;
    s.threads = 2;
    const RadiositySolution sol = SolveProgressive(scene, mesh, s);
    ASSERT_GT(sol.residual.size(), 100u);
    for (size_t i = 1; i < sol.residual.size(); ++i) ASSERT_LE(sol.residual[i], sol.residual[i - 1] * (1 + 1e-9)) << i;
    EXPECT_TRUE(sol.converged);
    EXPECT_LE(sol.residual.back(), 1e-3 * sol.entered_power);
    // The blocker shadows the floor under it: the floor's centre gets no direct light.
    double shadowed = -1, open = -1;
    for (size_t e = 0; e < mesh.elements().size(); ++e) {
        const RadiosityElement& el = mesh.elements()[e];
        if (el.n.y > 0.9f && el.center.y < 0.01f) {
            const float d = Length(el.center - Vec3(1.f, 0.f, 1.f));
            if (d < 0.2f) shadowed = sol.direct[2 * e].y;
            open = std::max(open, double(sol.direct[2 * e].y));
        }
    }
    EXPECT_EQ(shadowed, 0.0);
    EXPECT_GT(open, 0.0);
}

// A point light over a floor: the gathered direct radiosity is rho I cos / d^2 exactly
// (delta light, one sample suffices), the path by which points, distant lights and domes enter.
TEST(ProgressiveRadiosity, PointLightIsGatheredDirectly) {
    SceneDesc desc;
    const uint32_t floor = AddMaterial(desc, Color(0.5f), Color(0.f));
    AddQuad(desc, {-1, 0, -1}, {-1, 0, 1}, {1, 0, 1}, {1, 0, -1}, floor);
    PointLight pl{};
    desc.point_lights.push_back(pl);
    desc.point_lights.back().position = Vec3(0.f, 1.f, 0.f);
    desc.point_lights.back().intensity = Color(3.f);
    const Scene scene(desc);
    const RadiosityMesh mesh(scene, 0.1f);
    RadiositySettings s;
    s.element_size = 0.1f;
    s.threads = 2;
    const RadiositySolution sol = SolveProgressive(scene, mesh, s);
    for (size_t e = 0; e < mesh.elements().size(); ++e) {
        const Vec3 c = mesh.elements()[e].center;
        const float d2 = c.x * c.x + 1.f + c.z * c.z;
        const float want = 0.5f * 3.f * (1.f / std::sqrt(d2)) / d2;
        ASSERT_NEAR(sol.direct[2 * e].y / want, 1.f, 1e-3f) << e;
    }
}

}  // namespace
