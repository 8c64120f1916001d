// Progressive refinement radiosity (Cohen, Chen, Wallace & Greenberg 1988): Southwell
// iteration that repeatedly shoots the element side with the largest unshot power,
// B_j += rho_j F_ji dB_i for every receiver j, with the ambient term for display.
//
// Light enters in two steps, so the solution knows its direct component (the hybrid
// integrator traces that part itself):
//   1. lights that are not meshed (points, distant lights, the dome, sphere lights) are
//      gathered at every element by next event estimation, light_samples samples each;
//      emissive elements shoot their emission once. What this deposits is the direct part.
//   2. Southwell shooting of what remains unshot: the interreflection.
#pragma once

#include <cstdint>
#include <vector>

#include <tbb/task_arena.h>

#include "radiosity_mesh.h"

namespace tessera {

enum class RadiositySolver : uint8_t {
    // kStochastic above kAutoStochasticElements elements (the progressive solver's form
    // factors are O(n^2): 12 s at 4096 Cornell elements) or when the scene has delta
    // surfaces (only the stochastic solver carries light across them); else kProgressive.
    kAuto,
    kProgressive,   // Southwell shooting with form factors (SolveProgressive)
    kHierarchical,  // BF-refined links (hierarchical_solver.h)
    kStochastic,    // shooting by ray casting (stochastic_solver.h)
};

struct RadiositySettings {
    float element_size = 1.f;
    // Stop when the unshot power is below tolerance times the power that entered.
    float tolerance = 1e-3f;
    uint32_t max_shots = 0;      // 0: 100 per element
    uint32_t light_samples = 16; // per element side and non-meshed light
    uint32_t seed = 0;
    int threads = 0;             // 0: all
    static constexpr size_t kAutoStochasticElements = 4096;
    RadiositySolver solver = RadiositySolver::kProgressive;
    // Stochastic: rays of the first shot per element (later shots in proportion to the
    // power still unshot).
    float rays_per_element = 1024.f;
    // Stochastic: the first shot's rays in all when > 0 (else rays_per_element x elements).
    double first_rays = 0.0;
    // Adaptive meshing: after each solve, the uniform cells with an element whose display
    // vertices differ from it by more than refine_tolerance of the larger of the two (and
    // of a tenth of the mean) are halved, and the scene is solved again, refine_levels
    // times at most (radiosity_product.cpp).
    uint32_t refine_levels = 0;
    float refine_tolerance = 0.1f;
    // Also split an element where the display's direct light, interpolated from its
    // vertices to its centroid, differs from the direct light evaluated there by more than
    // this fraction of the larger (and of a hundredth of the mean): the interpolation
    // error itself, measured (point_direct.h). Linear interpolation of a quadratic misses
    // at an edge's midpoint up to 2.25 times what it misses at the centroid, so 0.5 % here
    // keeps a point's error near 1 % (at 1 % a sphere-lit plane had a point 1.8 % off).
    // 0: not this test.
    float direct_tolerance = 0.005f;
    // The default's refinement (refine_levels not given): rounds judged by the direct light's
    // interpolation error alone (direct_tolerance), which needs no solve, so the scene is
    // solved once, on the final mesh; the elements whose error is largest are split first,
    // up to refine_budget elements in all (radiosity_product.cpp).
    bool refine_by_direct = false;
    size_t refine_budget = size_t(1) << 22;
    // The shutter instant the solution holds (a moving scene solves one per time slice);
    // every ray and element of the solve sees the scene then.
    float shutter_time = 0.5f;
    uint32_t time_slices = 8;    // K for a scene with motion (radiosity_product.cpp)
};

struct RadiositySolution {
    // Per element side (index 2 e + side, side 0 the front), W m^-2:
    std::vector<Color> radiosity;  // B, emission included, ambient not
    std::vector<Color> direct;     // the reflected direct part of B (step 1)
    std::vector<Color> unshot;
    Color ambient;                 // the ambient radiosity estimate (Cohen et al. 1988)
    // Of the reflected power shot so far (emission's shots apart), luminance-weighted, what
    // reached a reflecting element: the scene's closure for light that is still unshot, which
    // scales the ambient term (an open scene loses the rest).
    double shot_power = 0.0, landed_power = 0.0;
    double emission_shot_power = 0.0, emission_landed_power = 0.0;
    // Unshot power (luminance-weighted W) before the first shot of step 2 and after every shot.
    std::vector<double> residual;
    double entered_power = 0.0;    // what step 1 put into the scene
    uint32_t shots = 0;            // progressive: shots; stochastic: iterations
    uint64_t rays = 0;             // stochastic: rays cast
    bool converged = false;
    size_t cached_factors = 0;     // form factors kept for reuse
    size_t links = 0;              // hierarchical: links between nodes (progressive: 0)
    size_t nodes = 0;              // hierarchical: quadtree nodes
};

// The scene's emitters that are not meshed (points, distant lights, the dome, spheres).
std::vector<uint32_t> UnmeshedLights(const Scene& scene, const RadiosityMesh& mesh);
// Irradiance at x (normal n) from those lights by next event estimation with shadow rays,
// `samples` samples each from sampler stream `stream` (a pure function of its arguments).
Color GatherIrradiance(const Scene& scene, Vec3 x, Vec3 n, const std::vector<uint32_t>& lights, uint32_t samples,
                       uint32_t seed, uint64_t stream, float eps);

RadiositySolution SolveProgressive(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings);

// A solution of `elements` elements with every array zeroed (converged when empty).
RadiositySolution ZeroSolution(size_t elements);
// Step 1a of every shooting solver: each element side's reflected irradiance from the
// unmeshed lights goes into sol's radiosity, direct and unshot (which must be zeroed).
void GatherUnmeshedDirect(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings,
                          tbb::task_arena& arena, RadiositySolution* sol);
// The ambient term from what is still unshot (Cohen et al. 1988), scaled by the closure
// landed_power / shot_power (the emission's when nothing else was shot; 1 when nothing was).
void SetAmbient(const RadiosityMesh& mesh, RadiositySolution* sol);

// The ambient-corrected reflected radiosity B - E + rho ambient, per element side.
std::vector<Color> ReflectedRadiosity(const RadiosityMesh& mesh, const RadiositySolution& solution);

}  // namespace tessera
