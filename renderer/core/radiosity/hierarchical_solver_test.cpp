// The hierarchical solver against the closed furnace box (B = E / (1 - rho), as for the
// progressive solver, progressive_solver_test.cpp) and against the progressive solver on
// a room with a light and a blocker, with its link count far below the element pairs.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "hierarchical_solver.h"
#include "radiosity_scenes.h"
#include "scene_helpers.h"

namespace {

using namespace tessera;
using namespace tessera_test;

constexpr float kPi = 3.14159265358979323846f;

TEST(HierarchicalRadiosity, ClosedBoxGivesEOverOneMinusRho) {
    for (float rho : {0.5f, 0.8f}) {
        // Every wall is a source here, so the BF oracle refines nearly everywhere: larger
        // elements than the progressive test's keep the links (and the time) in bounds.
        const FurnaceBox box(rho, 0.5f);
        const RadiosityMesh& mesh = box.mesh;
        const RadiositySolution sol = SolveHierarchical(box.scene, mesh, box.settings);
        const double want = kPi * FurnaceBox::kLe / (1.0 - rho);
        double worst = 0.0;
        for (size_t e = 0; e < mesh.elements().size(); ++e)
            worst = std::max(worst, std::abs(sol.radiosity[2 * e].y / want - 1.0));
        EXPECT_LT(worst, 0.01) << "rho " << rho << " links " << sol.links;
        std::printf("rho %.1f: worst %.4f, %zu links, %zu nodes, %zu elements\n", rho, worst, sol.links, sol.nodes,
                    mesh.elements().size());
    }
}

// The room (radiosity_scenes.h), per wall: the area-weighted mean radiosity of the
// hierarchical solution against the progressive one, at two oracle tolerances. Both
// solvers take an element's factor with the same estimator, so what separates them is the
// hierarchy: links above the elements, and leaves (8 per wall edge) finer than the
// progressive solver's elements (5). Measured (808 elements, 652864 element pairs): at
// 1e-4, 59591 links and -0.7 % to +0.3 % per wall; at 1e-5, 338369 links and -1.5 % to
// +0.1 % (the floor, lit only in the blocker's penumbra, which the finer leaves resolve
// better: its direct part is 12 % below the progressive solver's there).
TEST(HierarchicalRadiosity, AgreesWithProgressiveWithFewerLinksThanPairs) {
    const RadiosityRoom& room = RadiosityRoom::Get();
    const RadiositySolution p = SolveProgressive(room.scene, room.mesh, RadiosityRoom::Settings(1e-4f));
    const RadiositySolution coarse = SolveHierarchical(room.scene, room.mesh, RadiosityRoom::Settings(1e-4f));
    const RadiositySolution fine = SolveHierarchical(room.scene, room.mesh, RadiosityRoom::Settings(1e-5f));
    const size_t pairs = room.mesh.elements().size() * room.mesh.elements().size();
    const std::vector<double> ec = room.WallErrors(p, coarse), ef = room.WallErrors(p, fine);
    for (int w = 0; w < 6; ++w) {
        std::printf("wall %d: %+.4f (1e-4, %zu links), %+.4f (1e-5, %zu links); %zu pairs\n", w, ec[w], coarse.links,
                    ef[w], fine.links, pairs);
        EXPECT_LT(std::abs(ec[w]), 0.01) << w;
        EXPECT_LT(std::abs(ef[w]), 0.02) << w;
    }
    EXPECT_LT(coarse.links * 8, pairs);
    EXPECT_LT(fine.links * 1.5, pairs);
}

}  // namespace
