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
#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;

namespace {

constexpr uint32_t kW = 16, kH = 16;

// Row-major 3x4 translation.
std::vector<float> Translation(float x, float y, float z) { return {1, 0, 0, x, 0, 1, 0, y, 0, 0, 1, z}; }

// An emitting unit-wide quad x in [0, 1], y in [-1, 1] at depth z = -3, facing the camera
// at the origin, translated in x from x0 (shutter open) to x0 + distance (shutter close);
// a black backdrop behind it. With distance 0 and x0 = x it is the static scene.
SceneDesc SlidingEmitter(float le, float x0, float distance) {
    SceneDesc d;
    const uint32_t black = AddMaterial(d, Color(0.f), Color(0.f));
    const uint32_t emitter = AddMaterial(d, Color(0.f), Color(le));
    AddQuad(d, {-50, -50, -6}, {50, -50, -6}, {50, 50, -6}, {-50, 50, -6}, black);
    MeshDesc quad;
    quad.positions = {0, -1, -3, 1, -1, -3, 1, 1, -3, 0, 1, -3};
    quad.indices = {0, 1, 2, 0, 2, 3};
    quad.triangle_material = {emitter, emitter};
    d.prototypes.push_back(quad);
    d.instance_prototype = {0};
    d.instance_transforms = Translation(x0, 0, 0);
    if (distance != 0.f) {
        d.motion_instances = {0};
        d.motion_time_steps = {2};
        d.motion_transforms = Translation(x0, 0, 0);
        const std::vector<float> close = Translation(x0 + distance, 0, 0);
        d.motion_transforms.insert(d.motion_transforms.end(), close.begin(), close.end());
    }
    return d;
}

// An emitting quad y in [-1, 1] at z = -3 whose left edge runs from x = l0 to l1 and right
// edge from r0 to r1 over the shutter: a deforming prototype (vertex time steps), placed
// by a still instance. l0 = l1 = x0, r0 = r1 = x0 + 1: the still quad.
SceneDesc DeformingEmitter(float le, float l0, float l1, float r0, float r1) {
    SceneDesc d = SlidingEmitter(le, 0.f, 0.f);
    MeshDesc& quad = d.prototypes[0];
    quad.positions = {l0, -1, -3, r0, -1, -3, r0, 1, -3, l0, 1, -3};
    if (l0 != l1 || r0 != r1) quad.motion_positions = {l1, -1, -3, r1, -1, -3, r1, 1, -3, l1, 1, -3};
    return d;
}

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

// An orthographic view 4 units wide: column c sees x in [-2 + c / 4, -2 + (c + 1) / 4].
Camera OrthoView() {
    Camera cam = LookDownMinusZ({0, 0, 0}, kW, kH, 2.f);
    cam.projection = Projection::kOrthographic;
    return cam;
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

// Per-column means of rows [y0, y1) over K renders with seeds opt.seed + k: the mean and
// the variance of the K per-run values.
struct Profile {
    std::vector<double> mean, var;
};
Profile ColumnProfile(const std::function<std::vector<float>(uint32_t seed)>& render, uint32_t seed, int K,
                      uint32_t y0, uint32_t y1, int channel = 0) {
    std::vector<std::vector<double>> runs;
    for (int k = 0; k < K; ++k) {
        const std::vector<float> img = render(seed + uint32_t(k));
        std::vector<double> cols(kW, 0.0);
        for (uint32_t y = y0; y < y1; ++y)
            for (uint32_t x = 0; x < kW; ++x) cols[x] += img[4 * (kW * y + x) + channel] / double(y1 - y0);
        runs.push_back(cols);
    }
    Profile p{std::vector<double>(kW, 0.0), std::vector<double>(kW, 0.0)};
    for (uint32_t x = 0; x < kW; ++x) {
        for (int k = 0; k < K; ++k) p.mean[x] += runs[k][x] / K;
        for (int k = 0; k < K; ++k) p.var[x] += (runs[k][x] - p.mean[x]) * (runs[k][x] - p.mean[x]) / (K - 1);
    }
    return p;
}

// Columns of `p` (scaled by `scale`, shifted by `offset`) outside the one-sample t-test
// limit (K - 1 degrees of freedom) around the known `expected`; with `report`, each is
// reported and every column's limit must be at most `resolution`.
int FailingColumns(const Profile& p, double scale, double offset, const std::vector<double>& expected, int K,
                   double critical, double resolution, const std::string& what, bool report) {
    int failing = 0;
    for (uint32_t x = 0; x < kW; ++x) {
        const double se = std::sqrt(p.var[x] / K) * scale, value = scale * p.mean[x] + offset;
        if (report) EXPECT_LE(critical * se, resolution) << what << ": column " << x << " too noisy";
        if (std::abs(value - expected[x]) > std::max(critical * se, 1e-6)) {
            ++failing;
            if (report)
                ADD_FAILURE() << what << ": column " << x << " = " << value << ", expected " << expected[x] << " +- "
                              << critical * se;
        }
    }
    return failing;
}

std::vector<float> RenderWith(const Scene& scene, const Camera& cam, RenderOptions o, const char* integrator,
                              uint32_t seed) {
    o.integrator = integrator;
    o.seed = seed;
    const IntegratorInfo* info = FindIntegrator(integrator);
    if (info && info->scene_passes) o.scene_product = RunScenePass(scene, o, 0);
    return RenderResolved(scene, cam, o);
}

// Columns where `p` (scaled by `scale`, shifted by `offset`; K runs) and `ref` (K runs)
// differ by Welch's t beyond the two-sided limit at `alpha`. With `report`, each failing
// column is reported as `what` and every column's limit must be at most `resolution`, so
// that a control perturbed by more than twice that must fail.
int WelchFailingColumns(const Profile& p, double scale, double offset, const Profile& ref, int K, double alpha,
                        double resolution, const std::string& what, bool report) {
    int failing = 0;
    for (uint32_t x = 0; x < kW; ++x) {
        const double value = scale * p.mean[x] + offset;
        const Welch w = WelchT(value, scale * scale * p.var[x], K, ref.mean[x], ref.var[x], K);
        const double critical = StudentTCritical(alpha, w.df);
        if (report) EXPECT_LE(critical * w.se, resolution) << what << ": column " << x << " too noisy";
        if (std::abs(w.t) > critical && std::abs(value - ref.mean[x]) > 1e-6) {
            ++failing;
            if (report)
                ADD_FAILURE() << what << ": column " << x << " = " << value << ", reference " << ref.mean[x]
                              << " (t = " << w.t << ")";
        }
    }
    return failing;
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

TEST(Motion, VCMMergesWithLightVerticesOfItsOwnTimeSlice) {
    // A diffuse quad sliding across the view, lit by a point light at the camera: light
    // vertices land on the quad where it is at their path's instant. Merging a camera
    // vertex with light vertices from the whole shutter counts light that fell where the
    // quad was at other instants, and the blur comes out too dark (the coverage fraction
    // squared, about -35 % here where merging carries the light). Merging within the
    // camera sample's time slice agrees with path; a single slice (time_slices 1) must not.
    SceneDesc d = SlidingEmitter(0.f, -1.25f, 1.5f);
    d.materials[1].albedo = Color(0.8f);
    d.point_lights.push_back({Vec3(0, 0, 0), Color(40.f)});
    Scene moving(d);
    const Camera cam = OrthoView();
    const int K = 24;
    const RenderOptions o{1024, 0, 8, 2};
    const Profile ref =
        ColumnProfile([&](uint32_t seed) { return RenderWith(moving, cam, o, "path", seed); }, 3, K, 4, 12);
    double peak = 0;
    for (double v : ref.mean) peak = std::max(peak, v);
    ASSERT_GT(peak, 0.5);
    // A radius small beside the columns (0.25 wide), so the kernel's own bias at the
    // quad's edges stays well under 1 %; a million light paths so that merging, not only
    // the connections, carries part of the light in the default 32 slices. The light here
    // is direct (point light, quad, camera), which vcm merges only with direct_merging on.
    auto vcm = [&](float slices) {
        RenderOptions v = o;
        v.spp = 384;
        v.integrator_params = {{"light_paths", 1e6f}, {"radius", 0.02f}, {"direct_merging", 1.f}};
        if (slices > 0.f) v.integrator_params["time_slices"] = slices;
        return ColumnProfile([&](uint32_t seed) { return RenderWith(moving, cam, v, "vcm", seed); }, 101, K, 4, 12);
    };
    const double alpha = 1e-3 / double(kW);
    // Limits at most 1 % of the brightest column: the 2 % control must fail.
    auto failing = [&](const Profile& p, double scale, bool report) {
        return WelchFailingColumns(p, scale, 0.0, ref, K, alpha, 0.01 * peak, "vcm against path", report);
    };
    const Profile sliced = vcm(0.f);  // the default: 32 slices in the first iteration
    EXPECT_EQ(failing(sliced, 1.0, true), 0);
    EXPECT_GT(failing(sliced, 0.98, false), 0) << "the 2 % negative control passed";
    EXPECT_GT(failing(vcm(1.f), 1.0, false), 0) << "merging across the whole shutter passed";
}

TEST(Motion, TracedPhotonsLiveInTheirTimeSliceAndEachSliceCarriesTheFullFlux) {
    // The photon tracing sppm and photon share (photon_map.h): a point light of intensity I
    // at the origin over the sliding quad (z = -3) and its 100 x 100 backdrop (z = -6),
    // first landings only. Path i lives in slice i mod K: its photon on the quad lies
    // within the quad's sweep over that slice, and each slice's photons, Phi / n_b each,
    // carry the flux of every landing: I times the backdrop's solid angle (the quad lies
    // inside it), 4 arcsin(a^2 / (a^2 + d^2)) for half-side a = 50 at distance d = 6.
    SceneDesc d = SlidingEmitter(0.f, -1.25f, 1.5f);
    d.materials[0].albedo = Color(0.5f);  // the backdrop keeps its landings too
    d.materials[1].albedo = Color(0.8f);
    const float I = 2.f;
    d.point_lights.push_back({Vec3(0, 0, 0), Color(I)});
    const Scene moving(d);
    const uint32_t K = 8, N = 400000;
    const std::vector<StoredPhoton> photons =
        TracePhotons(moving, 5, 11, N, 0, PhotonFilter{}, ShutterSlices{K}, 2);
    // Photons on the quad outside the sweep of slice (b + shift) mod K.
    auto outside_sweep = [&](uint32_t shift) {
        int n = 0;
        for (const StoredPhoton& ph : photons) {
            if (std::abs(ph.p.z + 3.f) > 1e-3f) continue;
            const uint32_t b = (ph.time_slice + shift) % K;
            const float lo = -1.25f + 1.5f * float(b) / K, hi = -0.25f + 1.5f * float(b + 1) / K;
            n += (ph.p.x < lo - 1e-4f || ph.p.x > hi + 1e-4f);
        }
        return n;
    };
    EXPECT_EQ(outside_sweep(0), 0);
    EXPECT_GT(outside_sweep(1), 1000) << "the sweep check cannot see a photon at another slice's instant";
    // Per slice: the landing count is binomial (p = Omega / 4 pi), so the flux's relative
    // standard deviation is sqrt((1 - p) / (n_b p)), 0.33 % here; 4 sigma is 1.3 %.
    const double a = 50, dist = 6;
    const double omega = 4.0 * std::asin(a * a / (a * a + dist * dist));
    const double p = omega / (4.0 * kPi), expected = I * omega;
    std::vector<double> flux(K, 0.0);
    for (const StoredPhoton& ph : photons) flux[ph.time_slice] += ph.power.x;
    double total = 0;
    for (uint32_t b = 0; b < K; ++b) {
        const double sigma = expected * std::sqrt((1 - p) / (double(N / K) * p));
        EXPECT_NEAR(flux[b], expected, 4 * sigma) << "slice " << b;
        total += flux[b] / K;
    }
    // The slices' mean, 0.12 % standard deviation: a 2 % error in the flux fails.
    const double sigma_total = expected * std::sqrt((1 - p) / (double(N) * p));
    EXPECT_NEAR(total, expected, 4 * sigma_total);
    EXPECT_GT(std::abs(0.98 * total - expected), 4 * sigma_total) << "the 2 % negative control passed";
}

TEST(Motion, PhotonDensityOnAMovingReceiverIsTheTimeAverageOfStaticOnes) {
    // photon_direct sees the sliding quad's light only through photon density estimation:
    // merging a camera sample with photons from the whole shutter counts light that fell
    // where the quad was at other instants, and the blur comes out too dark (up to the
    // coverage fraction, squared). Against the mean of still photon_direct renders at
    // uniformly spaced instants, which has the same disk kernel's bias at the quad's
    // edges, the time kernel of K slices leaves about 1 / (4 K) of the peak where the
    // edges sweep (0.4 % for the K = 64 used here); time_slices 1 must fail.
    auto scene_at = [](bool moving, float at) {
        SceneDesc d = SlidingEmitter(0.f, moving ? -1.25f : -1.25f + 1.5f * at, moving ? 1.5f : 0.f);
        d.materials[1].albedo = Color(0.8f);
        d.point_lights.push_back({Vec3(0, 0, -1), Color(10.f)});
        return d;
    };
    const Scene moving(scene_at(true, 0.f));
    const int M = 16, K = 24;
    std::vector<std::unique_ptr<Scene>> instants;
    for (int m = 0; m < M; ++m) instants.push_back(std::make_unique<Scene>(scene_at(false, (m + 0.5f) / M)));
    const Camera cam = OrthoView();
    const float photons = 4e6f, radius = 0.1f;
    RenderOptions still{64, 0, 8, 2};
    still.integrator_params = {{"photons", photons / M}, {"radius", radius}};
    const Profile ref = ColumnProfile(
        [&](uint32_t seed) {
            std::vector<float> sum(size_t(kW) * kH * 4, 0.f);
            for (int m = 0; m < M; ++m) {
                const std::vector<float> img =
                    RenderWith(*instants[m], cam, still, "photon_direct", seed * 1000u + uint32_t(m));
                for (size_t i = 0; i < sum.size(); ++i) sum[i] += img[i] / M;
            }
            return sum;
        },
        500, K, 5, 11);
    double peak = 0;
    for (double v : ref.mean) peak = std::max(peak, v);
    ASSERT_GT(peak, 0.1);
    auto blurred = [&](float slices, float cost) {
        RenderOptions o{uint32_t(1024 * cost), 0, 8, 2};
        o.integrator_params = {{"photons", photons * cost}, {"radius", radius}, {"time_slices", slices}};
        return ColumnProfile([&](uint32_t seed) { return RenderWith(moving, cam, o, "photon_direct", seed); }, 700,
                             K, 5, 11);
    };
    const double alpha = 1e-3 / double(kW);
    // Limits at most 1.5 % of the brightest column: the 2 % control must fail.
    auto failing = [&](const Profile& p, double scale, bool report) {
        return WelchFailingColumns(p, scale, 0.0, ref, K, alpha, 0.015 * peak, "blurred against the still mean",
                                   report);
    };
    const Profile sliced = blurred(64.f, 1.f);
    EXPECT_EQ(failing(sliced, 1.0, true), 0);
    EXPECT_GT(failing(sliced, 0.98, false), 0) << "the 2 % negative control passed";
    // A quarter of the work suffices to see the whole-shutter estimate's tens of percent.
    EXPECT_GT(failing(blurred(1.f, 0.25f), 1.0, false), 0) << "density estimation across the whole shutter passed";
}

namespace {
// A diffuse wall (z = -3, 4 x 4, facing the camera) lit only by an emitting strip at
// z = -2 (facing the wall, y in [1.3, 1.7], 0.5 wide) whose centre slides from x = -1.5 to
// 1.5 over the shutter (moving), or stands where it is at instant `at` (still).
SceneDesc WallUnderASlidingStrip(bool moving, float at) {
    SceneDesc d;
    const uint32_t wall = AddMaterial(d, Color(0.8f), Color(0.f));
    const uint32_t glow = AddMaterial(d, Color(0.f), Color(40.f));
    AddQuad(d, {-2, -2, -3}, {2, -2, -3}, {2, 2, -3}, {-2, 2, -3}, wall);
    MeshDesc strip;  // facing -z, toward the wall
    strip.positions = {-0.25f, 1.3f, -2, -0.25f, 1.7f, -2, 0.25f, 1.7f, -2, 0.25f, 1.3f, -2};
    strip.indices = {0, 1, 2, 0, 2, 3};
    strip.triangle_material = {glow, glow};
    d.prototypes.push_back(strip);
    d.instance_prototype = {0};
    d.instance_transforms = Translation(moving ? -1.5f : -1.5f + 3.f * at, 0, 0);
    if (moving) {
        d.motion_instances = {0};
        d.motion_time_steps = {2};
        d.motion_transforms = Translation(-1.5f, 0, 0);
        const std::vector<float> close = Translation(1.5f, 0, 0);
        d.motion_transforms.insert(d.motion_transforms.end(), close.begin(), close.end());
    }
    return d;
}
}  // namespace

TEST(Motion, RadiositySolvesEachTimeSliceAtItsInstant) {
    // The wall's light comes from the sliding strip through the radiosity solution alone.
    // A moving scene is solved once per time slice at the slice's middle instant and each
    // camera sample reads its own slice's solution, so with K slices the blurred wall
    // equals the mean of K still renders at those instants (per column, Welch, limits at
    // most 1 % of the brightest column; the 2 % control fails). A single solution at
    // mid-shutter (time_slices 1) lights the wall where the strip is at mid-shutter only,
    // and fails. (hybrid reads the same RadiosityLookup past its first bounce; here its
    // direct light, by next event estimation at the instant, would hide the solution.)
    const int K = 8, seeds = 24;
    const Scene moving(WallUnderASlidingStrip(true, 0.f));
    std::vector<std::unique_ptr<Scene>> instants;
    for (int k = 0; k < K; ++k)
        instants.push_back(std::make_unique<Scene>(WallUnderASlidingStrip(false, (k + 0.5f) / K)));
    const Camera cam = OrthoView();
    for (const char* integrator : {"radiosity"}) {
        RenderOptions o{64, 0, 8, 2};
        o.integrator_params = {{"element_size", 0.4f}};
        RenderOptions still = o;
        still.spp = o.spp / 4;
        const Profile ref = ColumnProfile(
            [&](uint32_t seed) {
                std::vector<float> sum(size_t(kW) * kH * 4, 0.f);
                for (int k = 0; k < K; ++k) {
                    const std::vector<float> img = RenderWith(*instants[k], cam, still, integrator, seed);
                    for (size_t i = 0; i < sum.size(); ++i) sum[i] += img[i] / K;
                }
                return sum;
            },
            900, seeds, 4, 12);
        double peak = 0;
        for (double v : ref.mean) peak = std::max(peak, v);
        ASSERT_GT(peak, 0.05) << integrator;
        auto blurred = [&](float slices) {
            RenderOptions b = o;
            b.integrator_params["time_slices"] = slices;
            return ColumnProfile([&](uint32_t seed) { return RenderWith(moving, cam, b, integrator, seed); }, 950,
                                 seeds, 4, 12);
        };
        const double alpha = 1e-3 / double(kW);
        auto failing = [&](const Profile& p, double scale, bool report) {
            return WelchFailingColumns(p, scale, 0.0, ref, seeds, alpha, 0.01 * peak, integrator, report);
        };
        const Profile sliced = blurred(float(K));
        EXPECT_EQ(failing(sliced, 1.0, true), 0) << integrator;
        EXPECT_GT(failing(sliced, 0.98, false), 0) << integrator << ": the 2 % negative control passed";
        EXPECT_GT(failing(blurred(1.f), 1.0, false), 0) << integrator << ": one mid-shutter solution passed";
    }
}
