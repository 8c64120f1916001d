// UsdLux shaping on an area light: an emitting quad whose material carries a shaping
// (Material::emission_shaping) emits Le f(theta), theta off its emitting normal, with f the
// closed form of light_shaping.h (cone with a soft edge, focus with a tint), whichever way
// the renderer meets it -- a camera ray hitting it, next event estimation, an emission
// sample -- and path, light and bdpt agree on a floor it lights.
#include <gtest/gtest.h>

#include <cmath>

#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;

namespace {

constexpr float kLe = 5.f;

LightShaping ConeAndFocus() {
    LightShaping s;
    s.enabled = true;
    s.cutoff = 50.f * kPi / 180.f;
    s.smooth_start = 40.f * kPi / 180.f;
    s.focus = 2.f;
    s.focus_tint = Color(0.25f);
    return s;
}

// UsdLux's closed form, written out here (not light_shaping.h's code).
double ExpectedFactor(double theta) {
    const double cutoff = 50.0 * kPi / 180.0, start = 40.0 * kPi / 180.0;
    if (theta > cutoff) return 0.0;
    double f = 1.0;
    if (theta > start) {
        const double t = (theta - start) / (cutoff - start);
        f = 1.0 - t * t * (3.0 - 2.0 * t);
    }
    return f * (0.25 + 0.75 * std::pow(std::cos(theta), 2.0));
}

// A 0.2 x 0.2 quad at height 1 emitting downward (-y), over a grey floor at y = 0.
SceneDesc ShapedQuadOverFloor(bool shaped) {
    SceneDesc d = FloorScene(0.5f, 3.f);
    const uint32_t glow = AddMaterial(d, Color(0.f), Color(kLe));
    if (shaped) {
        d.materials[glow].emission_shaping = 0;
        d.emission_shapings.push_back(ConeAndFocus());
    }
    AddQuad(d, {-0.1f, 1, -0.1f}, {0.1f, 1, -0.1f}, {0.1f, 1, 0.1f}, {-0.1f, 1, 0.1f}, glow);
    return d;
}

}  // namespace

TEST(AreaLightShaping, EveryWayOfMeetingTheLightSeesLeTimesTheFactor) {
    const Scene scene(ShapedQuadOverFloor(true));
    ASSERT_EQ(scene.num_emitters(), 2u);  // the quad's two triangles
    for (double deg : {0.0, 20.0, 44.0, 48.0, 60.0}) {
        const double theta = deg * kPi / 180.0;
        const Vec3 toward(float(std::sin(theta)), -float(std::cos(theta)), 0.f);  // from the light, downward
        const float expected = float(kLe * ExpectedFactor(theta));
        // A ray from below (above the floor), travelling back along `toward`, hits the light at its centre.
        SurfaceHit hit;
        const Vec3 origin = Vec3(0, 1, 0) + toward * 0.5f;  // above the floor
        ASSERT_TRUE(scene.Intersect({origin, -toward}, &hit, 1e-4f));
        ASSERT_GE(scene.EmitterAt(hit), 0);
        EXPECT_NEAR(scene.Emitted(scene.EmitterAt(hit), hit, toward).x, expected, 1e-4f) << deg;
        // Next event estimation from that point toward the light.
        LightSample ls;
        ASSERT_TRUE(scene.SampleEmitter(0, origin, Vec2(0.3f, 0.3f), &ls));
        const double sampled_theta = std::acos(std::clamp(double(Dot(-ls.wi, Vec3(0, -1, 0))), -1.0, 1.0));
        EXPECT_NEAR(ls.radiance.x, kLe * ExpectedFactor(sampled_theta), 1e-4) << deg;
    }
    // Emission samples carry the factor of the direction they leave in.
    for (float u : {0.1f, 0.4f, 0.7f, 0.95f}) {
        EmissionSample es;
        ASSERT_TRUE(scene.SampleEmission(0, Vec2(0.3f, 0.6f), Vec2(u, 0.35f), 0.2f, &es));
        const double theta = std::acos(std::clamp(double(Dot(es.wo, Vec3(0, -1, 0))), -1.0, 1.0));
        EXPECT_NEAR(es.Le.x, kLe * ExpectedFactor(theta), 1e-4) << u;
        EXPECT_NEAR(es.beta.x, es.Le.x * kPi * 0.02f, 1e-4 + 1e-5 * es.beta.x) << u;  // Le pi A (one side)
    }
    // Unshaped, every direction sees Le.
    const Scene plain(ShapedQuadOverFloor(false));
    EmissionSample es;
    ASSERT_TRUE(plain.SampleEmission(0, Vec2(0.3f, 0.6f), Vec2(0.95f, 0.35f), 0.2f, &es));
    EXPECT_FLOAT_EQ(es.Le.x, kLe);
}

TEST(AreaLightShaping, PathLightAndBidirectionalAgreeOnTheShapedPool) {
    // The floor below shows the cone's pool of light; each integrator meets the shaping
    // another way (path: NEE and hits; light: emission samples; bdpt: all of them).
    const Scene scene(ShapedQuadOverFloor(true));
    // Looking straight down beside the light (its frustum misses the quad) at the pool's
    // edge: x from 0.35 to 1.25 on the floor, theta from 19 to 51 degrees.
    const Camera cam{{0.8f, 2.5f, 0}, Vec3(1, 0, 0), Vec3(0, 0, -1), Vec3(0, -1, 0), 0.3f, 0.3f, 16, 16};
    ExpectPathLightBDPTAgree(scene, cam, {256, 0, 4, 2}, 0, 16, 1e-3);
    SceneDesc bad = ShapedQuadOverFloor(true);
    bad.materials.back().emission_shaping = 1;  // beyond the list
    EXPECT_THROW(Scene{bad}, std::invalid_argument);
}
