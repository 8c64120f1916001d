// Moving lights: point, sphere and distant lights sliding over a lit plate against the
// closed-form irradiance, seen and sampled where they are at each instant, and the checks
// that static scenes carry no motion and invalid motion is refused.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "photon_map.h"
#include "motion_scenes.h"
#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;
using namespace motion_scenes;

namespace {

// Row-major 3x4 rotation by phi about +y.
std::vector<float> RotationY(float phi) {
    const float c = std::cos(phi), s = std::sin(phi);
    return {c, 0, s, 0, 0, 1, 0, 0, -s, 0, c, 0};
}

// A diffuse plate (albedo 0.5) at z = -3 facing the camera, lit by one light that moves;
// little wider than the 4 x 4 view, so that light paths mostly land where it is seen.
SceneDesc LitPlate() {
    SceneDesc d;
    const uint32_t grey = AddMaterial(d, Color(0.5f), Color(0.f));
    AddQuad(d, {-2.25f, -2.25f, -3}, {2.25f, -2.25f, -3}, {2.25f, 2.25f, -3}, {-2.25f, 2.25f, -3}, grey);
    return d;
}

void AddLightMotion(SceneDesc& d, LightKind kind, uint32_t index, const std::vector<std::vector<float>>& steps) {
    d.light_motion_kinds.push_back(kind);
    d.light_motion_indices.push_back(index);
    d.light_motion_time_steps.push_back(uint32_t(steps.size()));
    for (const auto& m : steps) d.light_motion_transforms.insert(d.light_motion_transforms.end(), m.begin(), m.end());
}

// Column means (rows 4-12: y in [-1, 1] on the plate) of the plate's radiance 0.5 / pi E
// under a light of intensity I at height h over it, sliding in x from xa to xb over the
// shutter: E = I h / d^3 (a sphere of radiance I / (pi r^2) gives the same, unoccluded and
// above the horizon). Midpoint rule in x, y and t.
std::vector<double> SlidingLightColumns(double I, double h, double xa, double xb) {
    const int n = 48;
    std::vector<double> cols(kW, 0.0);
    for (uint32_t c = 0; c < kW; ++c) {
        double sum = 0;
        for (int i = 0; i < n; ++i) {
            const double x = -2.0 + (c + (i + 0.5) / n) / 4.0;
            for (int j = 0; j < n; ++j) {
                const double y = -1.0 + 2.0 * (j + 0.5) / n;
                for (int k = 0; k < n; ++k) {
                    const double xl = xa + (xb - xa) * (k + 0.5) / n;
                    const double d2 = (x - xl) * (x - xl) + y * y + h * h;
                    sum += I * h / (d2 * std::sqrt(d2));
                }
            }
        }
        cols[c] = 0.5 / kPi * sum / (double(n) * n * n);
    }
    return cols;
}

}  // namespace

TEST(Motion, MovingPointSphereAndDistantLightsGiveTheClosedFormIrradiance) {
    // A point light and (in another scene) a sphere light of the same power slide 6 units
    // in x at height 3.5 over the plate (behind the pinhole, unseen); a distant light turns
    // from straight on to 60 degrees, so E = E0 cos(phi(t)) averages E0 sin(60) / (pi / 3).
    const double I = 6.0, h = 3.5, xa = -3.0, xb = 3.0, r = 0.25;
    const std::vector<double> sliding = SlidingLightColumns(I, h, xa, xb);
    const std::vector<double> frozen = SlidingLightColumns(I, h, 0.0, 0.0);
    SceneDesc point = LitPlate();
    point.point_lights.push_back({Vec3(0, 0, -3 + float(h)), Color(float(I))});
    AddLightMotion(point, kKindOf<PointLight>, 0, {Translation(float(xa), 0, 0), Translation(float(xb), 0, 0)});
    SceneDesc sphere = LitPlate();
    sphere.sphere_lights.push_back({Vec3(0, 0, -3 + float(h)), float(r), Color(float(I / (kPi * r * r)))});
    AddLightMotion(sphere, kKindOf<SphereLight>, 0, {Translation(float(xa), 0, 0), Translation(float(xb), 0, 0)});
    const float E0 = 2.f, turn = kPi / 3.f;
    SceneDesc distant = LitPlate();
    distant.distant_lights.push_back({Vec3(0, 0, -1), 0.f, Color(E0)});
    std::vector<std::vector<float>> turning;
    for (int k = 0; k < 65; ++k) turning.push_back(RotationY(turn * float(k) / 64.f));
    AddLightMotion(distant, kKindOf<DistantLight>, 0, turning);
    const std::vector<double> turned(kW, 0.5 / kPi * E0 * std::sin(turn) / turn), straight(kW, 0.5 / kPi * E0);

    struct Case {
        const char* name;
        const SceneDesc* desc;
        const std::vector<double>* expected;
        const std::vector<double>* frozen;
    };
    const std::vector<Case> cases{{"point", &point, &sliding, &frozen},
                                  {"sphere", &sphere, &sliding, &frozen},
                                  {"distant", &distant, &turned, &straight}};
    // Light tracing alone is left out (its splats would need 25 times the samples for 1 %
    // per column); bdpt's light subpaths start from the moving lights' SampleEmission,
    // which the next test checks at given instants.
    const std::vector<const char*> integrators{"path", "bdpt"};
    const int K = 16;
    const double critical = StudentTCritical(1e-3 / double(kW * integrators.size() * cases.size()), K - 1);
    const Camera cam = LookDownMinusZ({0, 0, 0}, kW, kH, 2.f / 3.f);  // sees x, y in [-2, 2] on the plate
    for (const Case& c : cases) {
        const Scene scene(*c.desc);
        ASSERT_TRUE(scene.has_motion()) << c.name;
        double peak = 0;
        for (double v : *c.expected) peak = std::max(peak, v);
        for (const char* integrator : integrators) {
            const std::string what = std::string(c.name) + " " + integrator;
            const Profile p = ColumnProfile(
                [&](uint32_t seed) {
                    const uint32_t spp = std::string(integrator) == "path" ? 256 : 512;
                    return RenderWith(scene, cam, {spp, 0, 8, 2}, integrator, seed);
                },
                41, K, 4, 12);
            // Limits at most 1 % of the brightest column: the image scaled by 0.98 and the
            // light frozen at mid-shutter must fail.
            EXPECT_EQ(FailingColumns(p, 1.0, 0.0, *c.expected, K, critical, 0.01 * peak, what, true), 0) << what;
            EXPECT_GT(FailingColumns(p, 0.98, 0.0, *c.expected, K, critical, 0.01 * peak, what, false), 0)
                << what << ": the 2 % negative control passed";
            EXPECT_GT(FailingColumns(p, 1.0, 0.0, *c.frozen, K, critical, 0.01 * peak, what, false), 0)
                << what << ": the frozen light passed";
        }
    }
}

TEST(Motion, MovingLightsAreSeenAndSampledWhereTheyAreAtTheInstant) {
    // An orthographic view of a sphere light (radius 0.5, in front of a black backdrop)
    // sliding from x = -1 to 0.5: each column is L x the fraction of the column-row-shutter
    // box inside the moving disk.
    const float L = 2.f;
    SceneDesc d = SlidingEmitter(0.f, 0.f, 0.f);
    d.sphere_lights.push_back({Vec3(0, 0, -3), 0.5f, Color(L)});
    AddLightMotion(d, kKindOf<SphereLight>, 0, {Translation(-1.f, 0, 0), Translation(0.5f, 0, 0)});
    const Scene scene(d);
    std::vector<double> expected(kW, 0.0);
    const int n = 80;  // the midpoint rule on the disk's indicator: within 1e-3 L of exact
    for (uint32_t c = 0; c < kW; ++c) {
        double sum = 0;
        for (int i = 0; i < n; ++i)
            for (int j = 0; j < n; ++j)
                for (int k = 0; k < n; ++k) {
                    const double x = -2.0 + (c + (i + 0.5) / n) / 4.0, y = -1.0 + 2.0 * (j + 0.5) / n;
                    const double xc = -1.0 + 1.5 * (k + 0.5) / n;
                    sum += (x - xc) * (x - xc) + y * y <= 0.25 ? 1.0 : 0.0;
                }
        expected[c] = L * sum / (double(n) * n * n);
    }
    const int K = 16;
    const double critical = StudentTCritical(1e-3 / double(kW), K - 1);
    const Profile p = ColumnProfile(
        [&](uint32_t seed) { return RenderWith(scene, OrthoView(), {512, 0, 8, 2}, "path", seed); }, 5, K, 4, 12);
    EXPECT_EQ(FailingColumns(p, 1.0, 0.0, expected, K, critical, 0.01 * L, "sphere", true), 0);
    EXPECT_GT(FailingColumns(p, 0.98, 0.0, expected, K, critical, 0.01 * L, "sphere", false), 0);

    // A textured dome (bright in one quarter of the sky) turning a quarter turn about y:
    // at each instant its radiance and sampling equal a still dome built turned by then.
    auto dome_scene = [](const float* world_to_light, bool moving) {
        SceneDesc s = LitPlate();
        s.dome_radiance = Color(1.f);
        s.dome_width = 8;
        s.dome_height = 4;
        for (uint32_t y = 0; y < 4; ++y)
            for (uint32_t x = 0; x < 8; ++x)
                for (int ch = 0; ch < 3; ++ch) s.dome_rgb.push_back(x < 2 ? 5.f : 0.2f);
        std::copy(world_to_light, world_to_light + 9, s.dome_world_to_light);
        if (moving) {
            std::vector<std::vector<float>> steps;
            for (int k = 0; k < 33; ++k) steps.push_back(RotationY(0.5f * kPi * float(k) / 32.f));
            AddLightMotion(s, kKindOf<DomeLight>, 0, steps);
        }
        return s;
    };
    const float identity[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    const Scene turning(dome_scene(identity, true));
    for (float t : {0.f, 0.25f, 1.f}) {
        // Turned by R: world direction w has the still dome's direction R^T w, so the still
        // dome's world_to_light is R^T (row-major: the rotation by -phi).
        const std::vector<float> rt = RotationY(-0.5f * kPi * t);
        const float turned[9] = {rt[0], rt[1], rt[2], rt[4], rt[5], rt[6], rt[8], rt[9], rt[10]};
        const Scene still(dome_scene(turned, false));
        const uint32_t dome = uint32_t(turning.num_emitters() - 1);
        ShutterTimeScope at(t);
        for (Vec2 u : {Vec2(0.1f, 0.3f), Vec2(0.6f, 0.9f), Vec2(0.95f, 0.05f)}) {
            LightSample a, b;
            ASSERT_TRUE(turning.SampleEmitter(dome, Vec3(0, 0, -2), u, &a));
            ASSERT_TRUE(still.SampleEmitter(dome, Vec3(0, 0, -2), u, &b));
            EXPECT_NEAR(Length(a.wi - b.wi), 0.f, 1e-4f) << "t = " << t;
            EXPECT_NEAR(a.pdf, b.pdf, 1e-3f * b.pdf) << "t = " << t;
            EXPECT_NEAR(a.radiance.x, b.radiance.x, 1e-4f * b.radiance.x) << "t = " << t;
            Color la(0.f), lb(0.f);
            float pa = 0.f, pb = 0.f;
            turning.ForEachEnvironmentLight(Vec3(0, 0, -2), a.wi, [&](uint32_t, Color l, float pdf) { la += l; pa += pdf; });
            still.ForEachEnvironmentLight(Vec3(0, 0, -2), a.wi, [&](uint32_t, Color l, float pdf) { lb += l; pb += pdf; });
            EXPECT_NEAR(la.x, lb.x, 1e-4f * lb.x);
            EXPECT_NEAR(pa, pb, 1e-3f * pb);
            EXPECT_NEAR(turning.InfiniteLightDensity(Vec3(0, 0, -2), a.wi), still.InfiniteLightDensity(Vec3(0, 0, -2), a.wi), 1e-3f * pb);
        }
    }
    // The turn is seen: at t = 1 the bright quarter has moved away from where it was at 0.
    LightSample first, last;
    {
        ShutterTimeScope at(0.f);
        turning.SampleEmitter(uint32_t(turning.num_emitters() - 1), Vec3(0, 0, -2), Vec2(0.1f, 0.3f), &first);
    }
    {
        ShutterTimeScope at(1.f);
        turning.SampleEmitter(uint32_t(turning.num_emitters() - 1), Vec3(0, 0, -2), Vec2(0.1f, 0.3f), &last);
    }
    EXPECT_GT(Length(first.wi - last.wi), 0.5f);

    // Light subpaths start where a moving light is at the instant: a point light sliding
    // from x = -1 to 3 and a distant light turning a quarter turn about y.
    SceneDesc lights = LitPlate();
    lights.point_lights.push_back({Vec3(0, 0, 0), Color(1.f)});
    AddLightMotion(lights, kKindOf<PointLight>, 0, {Translation(-1, 0, 0), Translation(3, 0, 0)});
    lights.distant_lights.push_back({Vec3(0, 0, -1), 0.f, Color(1.f)});
    AddLightMotion(lights, kKindOf<DistantLight>, 0, {RotationY(0.f), RotationY(0.25f * kPi), RotationY(0.5f * kPi)});
    const Scene moving_lights(lights);
    ASSERT_EQ(moving_lights.num_emitters(), 2u);  // the point, then the distant light
    for (float t : {0.f, 0.5f, 1.f}) {
        ShutterTimeScope at(t);
        EmissionSample es;
        ASSERT_TRUE(moving_lights.SampleEmission(0, Vec2(0.3f, 0.3f), Vec2(0.2f, 0.7f), 0.5f, &es));
        EXPECT_NEAR(Length(es.p - Vec3(-1.f + 4.f * t, 0, 0)), 0.f, 1e-5f) << "t = " << t;
        ASSERT_TRUE(moving_lights.SampleEmission(1, Vec2(0.3f, 0.3f), Vec2(0.2f, 0.7f), 0.5f, &es));
        const float phi = 0.5f * kPi * t;  // the step at t = 0.5 is on the arc: exact there too
        EXPECT_NEAR(Length(es.wo - Vec3(-std::sin(phi), 0, -std::cos(phi))), 0.f, 1e-5f) << "t = " << t;
        LightSample ls;
        ASSERT_TRUE(moving_lights.SampleEmitter(0, Vec3(0, 0, -3), Vec2(0.5f, 0.5f), &ls));
        EXPECT_NEAR(Length(ls.p - Vec3(-1.f + 4.f * t, 0, 0)), 0.f, 1e-5f);
        EXPECT_NEAR(Length(ls.wi - Normalize(Vec3(-1.f + 4.f * t, 0, 3))), 0.f, 1e-5f);
        EXPECT_NEAR(ls.distance, Length(Vec3(-1.f + 4.f * t, 0, 3)), 1e-5f);
    }
}

TEST(Motion, StaticScenesHaveNoMotionAndInvalidMotionIsRefused) {
    EXPECT_FALSE(Scene(SlidingEmitter(1.f, 0.f, 0.f)).has_motion());
    SceneDesc d = SlidingEmitter(1.f, 0.f, 1.f);
    d.motion_time_steps = {1};
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = SlidingEmitter(1.f, 0.f, 1.f);
    d.motion_transforms.pop_back();
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = SlidingEmitter(1.f, 0.f, 1.f);
    d.motion_transforms[12] = std::nanf("");
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = SlidingEmitter(1.f, 0.f, 1.f);
    d.motion_instances = {3};
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    // Deforming prototypes: whole steps of every vertex, finite, at most 129 steps in all.
    EXPECT_FALSE(Scene(DeformingEmitter(1.f, 0.f, 0.f, 1.f, 1.f)).has_motion());
    d = DeformingEmitter(1.f, 0.f, 1.f, 1.f, 2.f);
    d.prototypes[0].motion_positions.pop_back();
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = DeformingEmitter(1.f, 0.f, 1.f, 1.f, 2.f);
    d.prototypes[0].motion_positions[4] = std::nanf("");
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = DeformingEmitter(1.f, 0.f, 1.f, 1.f, 2.f);
    const std::vector<float> step = d.prototypes[0].motion_positions;
    for (int k = 0; k < 128; ++k)
        d.prototypes[0].motion_positions.insert(d.prototypes[0].motion_positions.end(), step.begin(), step.end());
    EXPECT_THROW(Scene{d}, std::invalid_argument);  // 130 steps
    // Moving lights: an existing light, listed once, 2 to 129 finite, invertible steps.
    SceneDesc lit = LitPlate();
    lit.point_lights.push_back({Vec3(0, 0, 0), Color(1.f)});
    AddLightMotion(lit, kKindOf<PointLight>, 0, {Translation(0, 0, 0), Translation(1, 0, 0)});
    EXPECT_TRUE(Scene(lit).has_motion());
    SceneDesc bad = lit;
    bad.light_motion_indices = {1};
    EXPECT_THROW(Scene{bad}, std::invalid_argument);
    bad = lit;
    bad.light_motion_kinds = {kKindOf<SphereLight>};
    EXPECT_THROW(Scene{bad}, std::invalid_argument);
    bad = lit;
    bad.light_motion_transforms[13] = std::nanf("");
    EXPECT_THROW(Scene{bad}, std::invalid_argument);
    bad = lit;
    bad.light_motion_transforms.pop_back();
    EXPECT_THROW(Scene{bad}, std::invalid_argument);
    bad = lit;
    AddLightMotion(bad, kKindOf<PointLight>, 0, {Translation(0, 0, 0), Translation(1, 0, 0)});
    EXPECT_THROW(Scene{bad}, std::invalid_argument);
    bad = lit;
    std::fill(bad.light_motion_transforms.begin(), bad.light_motion_transforms.begin() + 12, 0.f);
    EXPECT_THROW(Scene{bad}, std::invalid_argument);
}
