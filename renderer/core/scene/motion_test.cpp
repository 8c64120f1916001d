// Transform motion blur and deformation against closed forms and against time averages of
// static scenes: an emitting quad sliding (or deforming) across an orthographic view (each
// pixel = Le x the fraction of the pixel-and-shutter box the quad covers), and the shadow of a sliding occluder (the
// blurred image = the mean of static images at uniformly spaced instants).
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

// The column's mean over x and the shutter of "left(t) <= x <= right(t)", both edges
// linear in t (midpoint rule in x and t; 2000 x 2000 points keep it within 1e-3 of exact).
double EdgesColumn(uint32_t c, float le, float l0, float l1, float r0, float r1) {
    const int n = 2000;
    double sum = 0;
    for (int i = 0; i < n; ++i) {
        const double x = -2.0 + (c + (i + 0.5) / n) / 4.0;
        for (int j = 0; j < n; ++j) {
            const double t = (j + 0.5) / n;
            sum += (x >= l0 + (l1 - l0) * t && x <= r0 + (r1 - r0) * t) ? 1.0 : 0.0;
        }
    }
    return le * sum / (double(n) * n);
}

// The closed form: the mean over the column's x range and the shutter t in [0, 1] of
// "x0 + D t <= x <= x0 + D t + 1", i.e. t in [(x - 1 - x0) / D, (x - x0) / D] clipped to
// [0, 1], integrated over x by the midpoint rule (the integrand is piecewise linear in x).
double RampColumn(uint32_t c, float le, float x0, float distance) {
    const int n = 4000;
    double sum = 0;
    for (int i = 0; i < n; ++i) {
        const double x = -2.0 + (c + (i + 0.5) / n) / 4.0;
        double covered;
        if (distance == 0.f) {
            covered = (x >= x0 && x <= x0 + 1) ? 1.0 : 0.0;
        } else {
            const double lo = std::clamp((x - 1 - x0) / distance, 0.0, 1.0);
            const double hi = std::clamp((x - x0) / distance, 0.0, 1.0);
            covered = hi - lo;
        }
        sum += covered;
    }
    return le * sum / n;
}

}  // namespace


TEST(Motion, SlidingEmitterGivesTheClosedFormRampForEveryIntegratorThatSeesEmitters) {
    const float le = 2.f, x0 = -1.25f, distance = 1.5f;
    Scene moving(SlidingEmitter(le, x0, distance));
    ASSERT_TRUE(moving.has_motion());
    const Camera cam = OrthoView();
    std::vector<double> ramp, still;
    for (uint32_t c = 0; c < kW; ++c) {
        ramp.push_back(RampColumn(c, le, x0, distance));
        still.push_back(RampColumn(c, le, x0 + 0.5f * distance, 0.f));
    }
    // The ramp has partial columns on both sides (the test would not see a frozen quad).
    ASSERT_GT(ramp[4], 0.1 * le);
    ASSERT_LT(ramp[4], 0.9 * le);
    const int K = 24;
    // Integrators with a scene pass too: their camera samples have instants of their own,
    // whatever instants the product's photons or solution were made at.
    const std::vector<const char*> integrators{"path",   "light",  "bdpt",          "local",     "whitted",
                                               "vcm",    "photon", "photon_direct", "radiosity", "hybrid",
                                               "sppm"};
    const double critical = StudentTCritical(1e-3 / double(kW * integrators.size()), K - 1);
    // Every column's limit is at most 1 % of Le, so a 2 % error is found: the negative
    // controls -- the same check on the image scaled by 0.98, and against the frozen
    // mid-shutter quad -- must fail.
    const double resolution = 0.01 * le;
    for (const char* integrator : integrators) {
        const Profile p = ColumnProfile(
            [&](uint32_t seed) { return RenderWith(moving, cam, {512, 0, 8, 2}, integrator, seed); }, 11, K, 4, 12);
        EXPECT_EQ(FailingColumns(p, 1.0, 0.0, ramp, K, critical, resolution, integrator, true), 0) << integrator;
        EXPECT_GT(FailingColumns(p, 0.98, 0.0, ramp, K, critical, resolution, integrator, false), 0)
            << integrator << ": the 2 % negative control passed";
        EXPECT_GT(FailingColumns(p, 1.0, 0.0, still, K, critical, resolution, integrator, false), 0)
            << integrator << ": the frozen quad passed";
        // Rows above and below the quad see only the black backdrop.
        const std::vector<float> img = RenderWith(moving, cam, {64, 0, 8, 2}, integrator, 3);
        for (uint32_t y : {0u, 3u, 12u, 15u})
            for (uint32_t x = 0; x < kW; ++x) EXPECT_LE(img[4 * (kW * y + x)], 0.02f * le) << integrator;
    }
}

TEST(Motion, ACameraSlidingPastAStillQuadSeesTheSameRampAsTheQuadSlidingPastIt) {
    // The quad stands at x in [0, 1]; the orthographic camera slides from x = 1.25 to
    // x = -0.25 over the shutter, so in the camera's frame the quad slides from -1.25 to
    // 0.25: the closed-form ramp of the sliding-emitter test. Light tracing and bdpt
    // connect to the camera where it is at their sample's instant.
    const float le = 2.f, x0 = -1.25f, distance = 1.5f;
    Scene still(SlidingEmitter(le, 0.f, 0.f));
    ASSERT_FALSE(still.has_motion());
    Camera cam = OrthoView();
    auto poses = std::make_shared<std::vector<CameraPose>>();
    for (float x : {-x0, -x0 - distance}) poses->push_back({Vec3(x, 0, 0), cam.right, cam.up, cam.forward});
    cam.motion = poses;
    ASSERT_TRUE(cam.Moves());
    std::vector<double> ramp;
    for (uint32_t c = 0; c < kW; ++c) ramp.push_back(RampColumn(c, le, x0, distance));
    const int K = 24;
    const std::vector<const char*> integrators{"path", "light", "bdpt"};
    const double critical = StudentTCritical(1e-3 / double(kW * integrators.size()), K - 1);
    for (const char* integrator : integrators) {
        const Profile p = ColumnProfile(
            [&](uint32_t seed) { return RenderWith(still, cam, {512, 0, 8, 2}, integrator, seed); }, 11, K, 4, 12);
        EXPECT_EQ(FailingColumns(p, 1.0, 0.0, ramp, K, critical, 0.01 * le, integrator, true), 0) << integrator;
        EXPECT_GT(FailingColumns(p, 0.98, 0.0, ramp, K, critical, 0.01 * le, integrator, false), 0)
            << integrator << ": the 2 % negative control passed";
    }
    // At(t) interpolates the poses: mid-shutter is half-way, and the ends are the poses.
    EXPECT_NEAR(cam.At(0.5f).origin.x, -x0 - 0.5f * distance, 1e-6f);
    EXPECT_NEAR(cam.At(0.f).origin.x, -x0, 1e-6f);
    EXPECT_NEAR(cam.At(1.f).origin.x, -x0 - distance, 1e-6f);
    EXPECT_FALSE(cam.At(0.3f).Moves());
}

// A small emitter above a floor, a black occluder sliding under it: the blurred shadow
// equals the mean of static renders at the instants (m + 1/2) / M.
namespace {
SceneDesc SlidingOccluder(bool moving, float at) {
    SceneDesc d;
    const uint32_t floor = AddMaterial(d, Color(0.8f), Color(0.f));
    const uint32_t light = AddMaterial(d, Color(0.f), Color(30.f));
    const uint32_t black = AddMaterial(d, Color(0.f), Color(0.f));
    AddQuad(d, {-4, 0, -4}, {-4, 0, 4}, {4, 0, 4}, {4, 0, -4}, floor);                       // y = 0, up
    AddQuad(d, {-0.25f, 3, -0.25f}, {0.25f, 3, -0.25f}, {0.25f, 3, 0.25f}, {-0.25f, 3, 0.25f}, light);  // facing down
    MeshDesc occluder;  // a 0.5 x 0.5 square at height 1.5, both sides black
    occluder.positions = {-0.25f, 1.5f, -0.25f, 0.25f, 1.5f, -0.25f, 0.25f, 1.5f, 0.25f, -0.25f, 1.5f, 0.25f};
    occluder.indices = {0, 1, 2, 0, 2, 3};
    occluder.triangle_material = {black, black};
    d.prototypes.push_back(occluder);
    d.instance_prototype = {0};
    const float open = -0.6f, shift = 1.2f;
    d.instance_transforms = Translation(moving ? open : open + at * shift, 0, 0);
    if (moving) {
        d.motion_instances = {0};
        d.motion_time_steps = {3};  // three steps: a two-segment motion, linear overall
        for (float t : {0.f, 0.5f, 1.f}) {
            const std::vector<float> m = Translation(open + t * shift, 0, 0);
            d.motion_transforms.insert(d.motion_transforms.end(), m.begin(), m.end());
        }
    }
    return d;
}
}  // namespace

TEST(Motion, BlurredShadowEqualsTheTimeAverageOfStaticShadows) {
    // Looking straight down at the floor (up = -z), orthographic, 3 units wide: the
    // penumbra of the sliding occluder spans most columns.
    Camera cam{{0, 1.0f, 0}, Vec3(1, 0, 0), Vec3(0, 0, -1), Vec3(0, -1, 0), 1.5f, 1.5f, kW, kH};
    cam.projection = Projection::kOrthographic;
    Scene moving(SlidingOccluder(true, 0.f));
    const int M = 24, K = 16;
    std::vector<std::unique_ptr<Scene>> instants;
    for (int m = 0; m < M; ++m) instants.push_back(std::make_unique<Scene>(SlidingOccluder(false, (m + 0.5f) / M)));
    const RenderOptions opt{128, 0, 8, 2};
    // The reference: path tracing of the static scenes, averaged over the instants per seed.
    const Profile ref = ColumnProfile(
        [&](uint32_t seed) {
            std::vector<float> sum(size_t(kW) * kH * 4, 0.f);
            for (int m = 0; m < M; ++m) {
                const std::vector<float> img = RenderWith(*instants[m], cam, opt, "path", seed * 1000u + uint32_t(m));
                for (size_t i = 0; i < sum.size(); ++i) sum[i] += img[i] / M;
            }
            return sum;
        },
        100, K, 0, kH);
    double peak = 0;
    for (double v : ref.mean) peak = std::max(peak, v);
    ASSERT_GT(peak, 0.1);
    // Light tracing is left out: its splats are too noisy for 2 % here at a test's cost;
    // its light subpaths' instants are checked by the sliding emitter above. photon_direct
    // sees the floor's light only through its photons: a photon map made at mid-shutter
    // casts the frozen shadow, so this checks that photons live at instants of their own.
    const std::vector<const char*> integrators{"path", "bdpt", "photon_direct"};
    const double alpha = 1e-3 / double(kW * (integrators.size() + 1));  // Bonferroni
    for (const char* integrator : integrators) {
        const std::string name = integrator;
        RenderOptions o{M * opt.spp, 0, 8, 2};
        if (name == "path") o.spp = M * opt.spp / 4;
        if (name == "photon_direct") {
            // A camera sample sees the photons of its 1/32 of the shutter: at 256 samples a
            // pixel each photon is seen by about 4 samples (kernel disk: 0.6 pixel).
            o.spp = 256;
            o.integrator_params = {{"photons", 4000000.f}, {"radius", 0.08f}};
        }
        const Profile p =
            ColumnProfile([&](uint32_t seed) { return RenderWith(moving, cam, o, integrator, seed); }, 7, K, 0, kH);
        // Welch's t per column against the static average. Limits at most 1 % of the
        // brightest column, so the negative control -- the image brightened by 2 % of
        // that column -- must fail.
        auto failing = [&](double offset, bool report) {
            return WelchFailingColumns(p, 1.0, offset, ref, K, alpha, 0.01 * peak, integrator, report);
        };
        EXPECT_EQ(failing(0.0, true), 0) << integrator;
        EXPECT_GT(failing(0.02 * peak, false), 0) << integrator << ": the 2 % negative control passed";
    }
    // The frozen occluder (its mid-shutter shadow) differs from the blurred one.
    Scene frozen(SlidingOccluder(false, 0.5f));
    const Profile still = ColumnProfile([&](uint32_t seed) { return RenderWith(frozen, cam, opt, "path", seed); },
                                        300, K, 0, kH);
    EXPECT_GT(WelchFailingColumns(still, 1.0, 0.0, ref, K, alpha, 0.0, "frozen", false), 0)
        << "a frozen occluder casts the blurred shadow: the test cannot see motion";
}

TEST(Motion, DeformingEmittersGiveTheClosedFormCoverageForEveryIntegratorThatSeesEmitters) {
    // Two deformations of a still instance's prototype: every vertex sliding (the sliding
    // emitter's ramp, without a moving transform), and the right edge stretching the quad
    // from 0.5 to 2 units wide, so its area -- which light and bdpt sample by -- changes
    // during the shutter.
    const float le = 2.f;
    struct Case {
        const char* name;
        float l0, l1, r0, r1;
    };
    const std::vector<Case> cases{{"slide", -1.25f, 0.25f, -0.25f, 1.25f}, {"stretch", -1.f, -1.f, -0.5f, 1.f}};
    const std::vector<const char*> integrators{"path", "light", "bdpt", "local"};
    const int K = 24;
    const double critical = StudentTCritical(1e-3 / double(kW * integrators.size() * cases.size()), K - 1);
    // A pinhole whose view at z = -3 is the orthographic view's 4 x 4 units: the columns see
    // the same x ranges (and the shutter instants reach perspective camera rays too).
    const Camera cam = LookDownMinusZ({0, 0, 0}, kW, kH, 2.f / 3.f);
    for (const Case& c : cases) {
        Scene moving(DeformingEmitter(le, c.l0, c.l1, c.r0, c.r1));
        ASSERT_TRUE(moving.has_motion()) << c.name;
        std::vector<double> expected, frozen;
        for (uint32_t x = 0; x < kW; ++x) {
            expected.push_back(EdgesColumn(x, le, c.l0, c.l1, c.r0, c.r1));
            const float lm = 0.5f * (c.l0 + c.l1), rm = 0.5f * (c.r0 + c.r1);
            frozen.push_back(EdgesColumn(x, le, lm, lm, rm, rm));
        }
        for (const char* integrator : integrators) {
            const std::string what = std::string(c.name) + " " + integrator;
            const Profile p = ColumnProfile(
                [&](uint32_t seed) { return RenderWith(moving, cam, {512, 0, 8, 2}, integrator, seed); }, 31, K, 4,
                12);
            // Limits at most 1 % of Le: the image scaled by 0.98 and the frozen mid-shutter
            // shape must fail.
            EXPECT_EQ(FailingColumns(p, 1.0, 0.0, expected, K, critical, 0.01 * le, what, true), 0) << what;
            EXPECT_GT(FailingColumns(p, 0.98, 0.0, expected, K, critical, 0.01 * le, what, false), 0)
                << what << ": the 2 % negative control passed";
            EXPECT_GT(FailingColumns(p, 1.0, 0.0, frozen, K, critical, 0.01 * le, what, false), 0)
                << what << ": the frozen shape passed";
        }
    }
}

TEST(Motion, ADeformingEmitterIsSampledByItsAreaAtTheInstant) {
    // The stretching quad (2 units tall, 0.5 -> 2 wide) is two triangles of area w(t) each:
    // at every instant, emission points are drawn with area density 1 / w(t) and lie on
    // the quad as it is then, and next event estimation's solid-angle pdf is d^2 / (cos w(t)).
    const Scene scene(DeformingEmitter(2.f, -1.f, -1.f, -0.5f, 1.f));
    ASSERT_EQ(scene.num_emitters(), 2u);
    for (float t : {0.f, 0.3f, 1.f}) {
        const ShutterTimeScope at(t);
        const float w = 0.5f + 1.5f * t, right = -0.5f + 1.5f * t;
        for (uint32_t e = 0; e < 2; ++e) {
            EXPECT_NEAR(scene.EmissionPdfPosition(e), 1.f / w, 1e-5f) << "t = " << t;
            for (Vec2 u : {Vec2(0.1f, 0.2f), Vec2(0.9f, 0.7f), Vec2(0.5f, 0.99f)}) {
                EmissionSample es;
                ASSERT_TRUE(scene.SampleEmission(e, u, Vec2(0.3f, 0.6f), 0.2f, &es));
                EXPECT_NEAR(es.pdf_pos, 1.f / w, 1e-5f);
                EXPECT_GE(es.p.x, -1.f - 1e-5f);
                EXPECT_LE(es.p.x, right + 1e-5f) << "t = " << t << ": a point off the quad as it is now";
                LightSample ls;
                const Vec3 ref(0.f, 0.f, 0.f);
                ASSERT_TRUE(scene.SampleEmitter(e, ref, u, &ls));
                const Vec3 d = ls.p - ref;
                const float cos_light = std::abs(d.z) / Length(d);
                EXPECT_NEAR(ls.pdf, Dot(d, d) / (cos_light * w), 1e-4f * ls.pdf) << "t = " << t;
            }
        }
    }
}
