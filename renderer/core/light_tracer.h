// Light tracing (Arvo 1986; the lecture's method 9): paths start on lights, and every
// scattering vertex is connected to the pinhole camera through its importance function,
// splatting onto the full frame. Estimates the L(D)+E paths; light reaching the camera
// without scattering (emitters and the sky seen directly) comes from the camera rays of
// the tile's own pixels instead, as a pinhole can never be hit by a light path.
//
// Normalisation (see ResolveLightTracing): with We = 1 / (A cos^4 theta) over the image
// plane at distance 1 of area A, a pixel's value is sum(splats) * pixel_count / light_paths.
#pragma once

#include "camera.h"
#include "sampler.h"
#include "scene.h"
#include "splat_film.h"

namespace tessera {

// Connects point p (within p_error of its surface, geometric normal ng: for the ray
// offset) to the camera: false if the
// camera cannot see p (outside the image, beyond the clipping range, occluded). Writes the
// raster position, the unit direction to the camera and the importance estimate
// We cos_camera / (d^2 pdf_lens) = 1 / (A cos^3 theta_camera d^2) (the lens area cancels).
// With a thin lens, u_lens picks the lens point the connection goes to; *lens_point gets it.
bool ConnectToCamera(const Scene& scene, const Camera& camera, Vec3 p, float p_error, Vec3 ng, Vec2 u_lens, float* px, float* py,
                     Vec3* wc, float* importance_over_d2, Vec3* lens_point = nullptr);

struct LightTraceStats {
    uint64_t rejected_splats = 0;  // non-finite, negative or unrepresentable: a bug if > 0
};

class LightTracer {
public:
    explicit LightTracer(int max_depth) : max_depth_(max_depth) {}
    // Traces one light path with the given sampler and splats its camera connections.
    void Trace(const Scene& scene, const Camera& camera, PixelSampler& sampler, SplatFilm& film,
               LightTraceStats* stats) const;

private:
    int max_depth_;
};

}  // namespace tessera
