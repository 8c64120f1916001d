// The radiosity solution as a scene-wide product (docs/integrators.md, "Scene-wide
// passes"): the reflected radiosity, and its direct part, per element side and per display
// vertex side. No geometry: every reader rebuilds the same RadiosityMesh from the scene
// and element_size, and the product names its element and vertex counts to check that.
//
// A scene with motion is solved once per time slice of the shutter (`time_slices`, K,
// default 8; shutter_slices.h): slice k's mesh and solution hold the scene at the instant
// (k + 1/2) / K, and a camera sample reads the solution of the slice holding its own
// instant, so the diffuse light moves with the scene (a time kernel 1/K wide; the solve
// costs K times a still one). A still scene has one slice, the solution it always had.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "integrator.h"
#include "progressive_solver.h"
#include "radiosity_mesh.h"

namespace tessera {

// The settings the radiosity and hybrid integrators share, and their parsing
// (IntegratorSettings -> RadiositySettings; throws std::invalid_argument on bad values).
const std::vector<IntegratorParam>& RadiosityParams();
RadiositySettings RadiositySettingsFrom(const IntegratorSettings& s, const Scene& scene, const char* who);
// `interpolate`: the display reads smooth vertex interpolation by default; a final gather
// reads each element's own mean, which integrates to the solution (on the Lambertian Cornell
// box at element size 100 the hybrid's ceiling is 2.1 % dark when gathering the
// interpolated values, 0.9 % with the constant ones).
bool RadiosityInterpolates(const IntegratorSettings& s, const char* who, bool by_default);

// Solves and encodes: what RunScenePass of both integrators returns.
std::string SolveRadiosityProduct(const Scene& scene, const RadiositySettings& settings);

// The solve behind it, at settings.shutter_time: the chosen solver on the uniform mesh,
// then refine_levels rounds of adaptive refinement (each re-meshes and solves again).
struct SolvedRadiosity {
    std::unique_ptr<RadiosityMesh> mesh;
    RadiositySolution solution;
    // The reflected direct radiosity evaluated at each display vertex side
    // (VertexPointDirect; empty beyond its budget, then the display averages).
    std::vector<Color> vertex_direct;
};
SolvedRadiosity SolveRadiosity(const Scene& scene, const RadiositySettings& settings);
// The default's refinement: the leaf depths of the next round's mesh, every element whose
// display (its vertices' point-evaluated direct light, averaged) misses the direct light
// evaluated at its centroid by more than `tolerance` of the larger (and of a hundredth of
// the mean) split in four, the largest misses first while the mesh stays within `budget`
// elements. Empty when nothing changes.
std::vector<uint8_t> DirectRefinedDepths(const RadiosityMesh& mesh, const std::vector<Color>& vertex_direct,
                                         const std::vector<Color>& centroid_direct, float tolerance, size_t budget);
// The leaf depths of the next round's mesh: every element one of whose display vertices
// differs from it by more than `tolerance` of the larger of the two (or of a tenth of the
// mean reflected radiosity) is split in four. Empty when nothing changes or
// kMaxElements would be passed.
// With vertex_direct and centroid_direct (the point-evaluated direct part at the display
// vertices and the element centroids, point_direct.h), an element is also split where the
// mean of its vertices' values misses its centroid's by more than direct_tolerance.
std::vector<uint8_t> RefinedDepths(const RadiosityMesh& mesh, const RadiositySolution& solution, float tolerance,
                                   const std::vector<Color>* vertex_direct = nullptr,
                                   const std::vector<Color>* centroid_direct = nullptr, float direct_tolerance = 0.f);

// A tile's view of a product: the radiosity leaving a surface point.
class RadiosityLookup {
public:
    RadiosityLookup(const Scene& scene, float element_size, const std::string& product, bool interpolate,
                    const char* who);
    // Reflected radiosity (W m^-2, emission excluded, ambient included) leaving the hit on
    // the side wo points to, and its direct part; false if the hit is on no element.
    bool Reflected(const SurfaceHit& hit, Vec3 wo, Color* reflected, Color* direct) const;

    // One time slice's mesh (built at its instant) and solution.
    struct Data {
        Data(const Scene& scene, float element_size, const std::vector<uint8_t>& leaf_depth)
            : mesh(scene, element_size, leaf_depth) {}
        RadiosityMesh mesh;
        std::vector<Color> element_reflected, element_direct, vertex_reflected, vertex_direct;
    };
    using Slices = std::vector<std::unique_ptr<const Data>>;

private:
    std::shared_ptr<const Slices> data_;
    bool interpolate_;
};

}  // namespace tessera
