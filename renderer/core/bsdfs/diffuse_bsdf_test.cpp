// DiffuseBSDF: the properties every kind has (bsdf_checks.h: chi-square of its sampling,
// Sample_f against f and PDF, reciprocity, the white furnace at exactly 1, finiteness),
// each with its negative control.
#include <gtest/gtest.h>

#include <vector>

#include "bsdf_checks.h"
#include "diffuse_bsdf.h"

using namespace tessera;
using namespace tessera::testing;

namespace {

std::vector<NamedBSDF> DiffuseCases(TransportMode, bool white) {
    const Color tint = white ? Color(1.f) : Color(0.8f, 0.5f, 0.2f);
    return {{"diffuse", DiffuseBSDF(tint), white}};
}

}  // namespace

TEST(DiffuseBSDF, SamplingFollowsPdf) { ExpectSamplingFollowsPdf(DiffuseCases, 2000); }
TEST(DiffuseBSDF, WhiteFurnaceAtMostOne) { ExpectWhiteFurnaceAtMostOne(DiffuseCases); }
TEST(DiffuseBSDF, SampleAgreesReciprocalAndFinite) { ExpectConsistentReciprocalAndFinite(DiffuseCases); }

TEST(DiffuseBSDF, FurnaceDetectsEnergyGain) {
    // Negative control: the bound must catch a surface that reflects 3% too much.
    Furnace fu = WhiteFurnace(DiffuseBSDF(Color(1.03f)), Dir(0.5f, 0.f), TransportMode::Radiance);
    EXPECT_GT(fu.mean.x, 1.f + 5.f * fu.stderr_.x + 1e-4f);
}
