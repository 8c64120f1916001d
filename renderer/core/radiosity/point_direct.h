// The direct light evaluated at points (Cohen & Wallace 1993, ch. 9.2: radiosities computed
// at the vertices for display) rather than averaged over elements. An element's direct
// radiosity is its mean over its area; interpolating those means between display vertices
// (each the mean of its elements) flattens every peak and pulls every border towards the
// inside: under a small light a lit plane showed 9 % too little at the spot straight below
// it and 30 to 45 % too much near its edges at the default element size. The direct part
// is where the radiosity varies fastest, and it is known in closed form point by point:
// the exact point-to-polygon factor of each emissive element (Lambert's contour integral,
// form_factor.h) times its visibility, and next event estimation for the lights that are
// not meshed. So the display's vertices take the direct part evaluated at the vertex,
// the smooth interreflected rest as before (the area-weighted mean of its elements), and
// the adaptive meshing compares the display's interpolation against the same evaluation
// at each element's centroid (radiosity_product.cpp).
#pragma once

#include <vector>

#include <tbb/task_arena.h>

#include "progressive_solver.h"

namespace tessera {

// A point's NEE takes this many times light_samples of each unmeshed light: an element
// side's samples are averaged over its area by its neighbours' in the vertex mean, a point's
// are not (a sphere light at 16 samples left single vertices 4 % off).
constexpr uint32_t kPointSamplesPerLightSample = 16;

class PointDirect {
public:
    PointDirect(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings);
    // Direct irradiance at x on the side facing n (W m^-2): emission x factor from every
    // emissive element (visibility by one shadow ray to each of its 4 half-edge
    // sub-triangles' centroids), plus `light_samples` NEE samples of each unmeshed light
    // (times kPointSamplesPerLightSample) from sampler stream `stream` (a pure function of its
    // arguments).
    Color Irradiance(Vec3 x, Vec3 n, uint64_t stream) const;
    // What one point costs, in shadow rays: 4 per emissive element, and the NEE samples.
    size_t cost() const {
        return 4 * emissive_.size() + size_t(kPointSamplesPerLightSample) * settings_.light_samples * unmeshed_.size() +
               1;
    }

private:
    const Scene& scene_;
    const RadiosityMesh& mesh_;
    RadiositySettings settings_;
    std::vector<uint32_t> emissive_;  // elements with emission on some side
    std::vector<uint32_t> unmeshed_;
    float eps_;
};

// The reflected direct radiosity evaluated at each display vertex side (index 2 v + side),
// rho the area-weighted mean of the elements meeting there, hanging vertices settled
// along their coarse edges as in VertexAverage. Empty when the evaluation would exceed
// kPointDirectBudget (vertex sides x PointDirect::cost()): the display then keeps the
// vertex averages.
constexpr double kPointDirectBudget = double(1u << 25);
std::vector<Color> VertexPointDirect(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings,
                                     tbb::task_arena& arena);
// The same at each element side's centroid (index 2 e + side), times the element's rho.
std::vector<Color> CentroidPointDirect(const Scene& scene, const RadiosityMesh& mesh,
                                       const RadiositySettings& settings, tbb::task_arena& arena);

}  // namespace tessera
