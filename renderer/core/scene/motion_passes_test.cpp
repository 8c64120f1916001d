// Motion blur in the integrators with scene passes: VCM merges within its own time slice,
// photons live in their slice with the full flux, photon density on a moving receiver and
// radiosity solved per time slice, each against path or the time average of static scenes.
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
