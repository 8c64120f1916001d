// Next event estimation at one surface point, shared by the integrators that shade with
// light sampling (path, local, whitted).
#pragma once

#include "bsdf.h"
#include "sampler.h"
#include "scene.h"

namespace tessera {

// One light sample at a surface: Le f |cos| / pdf through the BSDF's non-delta lobes, with
// a shadow ray. With `mis`, weighted by the power heuristic against BSDF sampling of the
// same direction (delta lights always get weight 1).
Color SampleDirectLight(const Scene& scene, const SurfaceHit& hit, const BSDF& bsdf, const Frame& frame, Vec3 wo,
                        PixelSampler& sampler, bool mis);

}  // namespace tessera
