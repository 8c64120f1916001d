// Hierarchical radiosity (Hanrahan, Salzman & Aupperle 1991): each scene triangle is the
// root of a quadtree of midpoint subdivisions, and energy moves along links between nodes
// at whatever level the transfer is accurate enough for. A link from q to p is refined
// (the larger of the two split in four) while the BF oracle rho_p F_pq B_q exceeds
// `tolerance` times the brightest emission, down to the element size; the linking is
// redone twice with the solved B (emitters first, then everything that reflects). Gathering
// with push-pull (Jacobi iterations) solves the linked system. The result is sampled at
// the uniform mesh's elements (each takes the leaf that contains its centre), so the
// product, the display interpolation and every reader are the progressive solver's.
#pragma once

#include "progressive_solver.h"

namespace tessera {

RadiositySolution SolveHierarchical(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings);

}  // namespace tessera
