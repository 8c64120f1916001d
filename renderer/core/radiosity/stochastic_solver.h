// Stochastic progressive radiosity (shooting by ray casting; Neumann et al. 1995, Bekaert
// 1999 "stochastic Jacobi"; Keller 1996 for the quasi-random rays): no form factor is ever
// computed. Each iteration every element side with unshot power shoots it along rays,
// their number proportional to its power (each ray carries the same luminance power),
// from uniformly chosen points in cosine-distributed directions; the element side a ray
// reaches receives the ray's power times its reflectance. A ray samples F_ij exactly (the
// fraction of i's cosine-weighted hemisphere that reaches j is F_ij, occlusion included),
// so the solution is unbiased in the element basis, and the cost is O(rays), not O(n^2):
// this is the solver for scenes of 10^5 triangles and more.
//
// The first iteration shoots the emitters' emission alone (what it deposits is the direct
// part, as in the progressive solver); unmeshed lights are gathered as there. Iteration i
// casts rays_per_element x elements x U_i / U_0 rays (U the unshot power: the allocation
// that minimises the summed variance for a given number of rays), until U_i falls below
// tolerance x the entered power; the remainder becomes the ambient term.
//
// Deterministic for any thread count: the rays of element side k are Owen-scrambled Sobol
// points of its own stream, and the deposits are summed in ray order, block by block.
#pragma once

#include "progressive_solver.h"

namespace tessera {

RadiositySolution SolveStochastic(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings);

}  // namespace tessera
