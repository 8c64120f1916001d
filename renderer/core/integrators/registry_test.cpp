// The registry: names are unique, the `auto` rule follows the capabilities, and the
// splatting capability is what RenderTile actually enforces.
#include <gtest/gtest.h>

#include <algorithm>
#include <iterator>
#include <set>
#include <string>
#include <vector>

#include "integrator.h"
#include "render.h"
#include "scene_helpers.h"

namespace {

using namespace tessera;
using namespace tessera_test;

TEST(Registry, NamesAreUniqueAndEveryEntryBuildsItsOwnIntegrator) {
    const Scene scene(FloorScene(0.5f));
    std::set<std::string> names;
    for (const IntegratorInfo& info : RegisteredIntegrators()) {
        EXPECT_TRUE(names.insert(std::string(info.name)).second) << info.name;
        EXPECT_FALSE(info.description.empty()) << info.name;
        EXPECT_EQ(FindIntegrator(info.name), &*FindIntegrator(info.name));
        EXPECT_EQ(Integrator::Create(info.name, {}, scene)->info().name, info.name);
        // Nothing may stop per tile while its splats land on other tiles.
        EXPECT_FALSE(info.splats && info.stop_per_tile) << info.name;
    }
    EXPECT_EQ(FindIntegrator("auto"), nullptr);  // a rule, not an integrator
}

// The integrator matrix (tests/renderer/test_integrator_matrix.py) skips a scene for an
// integrator only where its entry says why: a complete integrator may skip none, and every
// exclusion names a known class and gives a reason.
TEST(Registry, BlindnessIsDeclaredWithReasonsAndCompleteIntegratorsSeeEveryPath) {
    for (const IntegratorInfo& info : RegisteredIntegrators()) {
        for (const PathExclusion& x : info.blind_to) {
            EXPECT_NE(std::find(std::begin(kPathClasses), std::end(kPathClasses), x.paths), std::end(kPathClasses))
                << info.name << ": " << x.paths;
            EXPECT_GT(x.reason.size(), 20u) << info.name << ": " << x.paths;
        }
        if (info.complete) {
            EXPECT_TRUE(info.blind_to.empty()) << info.name;
            EXPECT_EQ(info.estimates, "radiance") << info.name;
        }
    }
}

TEST(Registry, AutoPicksTheFirstCompleteIntegratorThatHandlesTheScene) {
    for (bool caustics : {false, true}) {
        const IntegratorInfo* chosen = FindIntegrator(AutoIntegrator(caustics));
        ASSERT_NE(chosen, nullptr);
        EXPECT_TRUE(chosen->complete);
        if (caustics) EXPECT_TRUE(chosen->delta_caustics);
        for (const IntegratorInfo& info : RegisteredIntegrators()) {  // none earlier qualifies
            if (&info == &*std::find_if(RegisteredIntegrators().begin(), RegisteredIntegrators().end(),
                                        [&](const IntegratorInfo& i) { return i.name == chosen->name; }))
                break;
            EXPECT_FALSE(info.complete && (info.delta_caustics || !caustics)) << info.name;
        }
    }
}

// What `auto`'s pilot reads (tessera_base.integrators.pilot_candidates, merging_alpha): an
// always-candidate is complete, a mirrors-or-glass one is a merging integrator (its alpha a
// radius exponent in (0, 1), its iterations batches), and at least one candidate remains for
// a scene with delta-light caustics. The preview's integrator is the one view-independent
// product, made by a scene pass.
TEST(Registry, PilotCandidatesAndThePreviewFollowTheCapabilities) {
    using Pilot = IntegratorInfo::PilotCandidate;
    int always = 0, with_caustics = 0, previews = 0;
    for (const IntegratorInfo& info : RegisteredIntegrators()) {
        const bool merging = info.merging_alpha != 0;
        if (merging) {
            EXPECT_GT(info.merging_alpha, 0.0) << info.name;
            EXPECT_LT(info.merging_alpha, 1.0) << info.name;
            EXPECT_FALSE(info.iteration_cap.param.empty()) << info.name;
        }
        if (info.pilot_candidate == Pilot::kAlways) {
            EXPECT_TRUE(info.complete) << info.name;
            ++always;
            with_caustics += info.delta_caustics;
        }
        if (info.pilot_candidate == Pilot::kMirrorsOrGlassWithNoiseTarget) EXPECT_TRUE(merging) << info.name;
        if (info.view_independent_product) {
            EXPECT_TRUE(info.scene_passes) << info.name;
            ++previews;
        }
    }
    EXPECT_GE(always, 2);  // a pilot of one candidate would measure nothing
    EXPECT_GE(with_caustics, 1);
    EXPECT_EQ(previews, 1);
}

TEST(Registry, SplattingIntegratorsRefuseToRenderWithoutASplatBuffer) {
    const Scene scene(FloorScene(0.5f));
    const Camera camera = LookDownAtOrigin(1.f, 4);
    std::vector<float> rgba(4 * 4 * 4);
    for (const IntegratorInfo& info : RegisteredIntegrators()) {
        RenderOptions opt;
        opt.spp = 1;
        opt.integrator = std::string(info.name);
        if (info.scene_passes) opt.scene_product = RunScenePass(scene, opt, 0);
        if (info.splats)
            EXPECT_THROW(RenderTile(scene, camera, opt, {0, 0, 4, 4}, rgba.data()), std::invalid_argument) << info.name;
        else
            EXPECT_EQ(RenderTile(scene, camera, opt, {0, 0, 4, 4}, rgba.data()).light_paths, 0u) << info.name;
    }
}

}  // namespace

// The capped doubling schedule (IterationBatches, IterationShareCap): iteration shares 1, 1,
// 2, 4, ..., C, C, ... of batches, contiguous from batch 1, with C the largest power of two
// of batches an iteration may hold. Expected values written out by hand, not recomputed.
TEST(Registry, IterationBatchesDoubleUpToTheCapThenStay) {
    EXPECT_EQ(IterationShareCap(1e5, 4e6), 32u);  // 40 batches fit: 32 is the power of two
    EXPECT_EQ(IterationShareCap(1e5, 1e7), 64u);
    EXPECT_EQ(IterationShareCap(2000, 8000), 4u);
    EXPECT_EQ(IterationShareCap(3e6, 4e6), 1u);   // one batch always
    EXPECT_EQ(IterationShareCap(5e6, 4e6), 1u);
    const uint64_t first[] = {1, 2, 3, 5, 9, 13, 17};
    const uint64_t count[] = {1, 1, 2, 4, 4, 4, 4};
    for (uint32_t k = 0; k < 7; ++k) {
        const BatchRange b = IterationBatches(k, 4);
        EXPECT_EQ(b.first, first[k]) << k;
        EXPECT_EQ(b.count, count[k]) << k;
    }
    // Uncapped in practice: the old doubling (first 2^(k-1) + 1, count 2^(k-1)).
    for (uint32_t k = 1; k < 20; ++k) {
        EXPECT_EQ(IterationBatches(k, uint64_t(1) << 30).first, (uint64_t(1) << (k - 1)) + 1) << k;
        EXPECT_EQ(IterationBatches(k, uint64_t(1) << 30).count, uint64_t(1) << (k - 1)) << k;
    }
    // Contiguous for every cap.
    for (uint64_t cap : {1u, 2u, 8u, 32u})
        for (uint32_t k = 0; k < 40; ++k)
            EXPECT_EQ(IterationBatches(k, cap).first + IterationBatches(k, cap).count, IterationBatches(k + 1, cap).first)
                << cap << " " << k;
}
