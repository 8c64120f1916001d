// Renders a rectangle of the image into float RGBA. The result for a pixel depends only
// on (scene, camera, pixel, spp, seed, max_depth): the tile rectangle and thread count
// only decide who computes it.
#pragma once

#include <algorithm>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "camera.h"
#include "sampler.h"
#include "scene.h"

namespace tessera {

struct TileRect {
    uint32_t x0 = 0, y0 = 0, width = 0, height = 0;
    bool Contains(uint32_t x, uint32_t y) const { return x - x0 < width && y - y0 < height; }
};

struct RenderOptions {
    uint32_t spp = 16;  // samples per pixel in this call
    uint32_t seed = 0;
    int max_depth = 64;
    int threads = 0;            // 0: all hardware threads
    uint32_t sample_start = 0;  // index of the first sample: passes [a, b) and [b, c) compose into [a, c)
    std::string integrator = "path";  // a registered name (integrators/integrator.h)
    std::map<std::string, float> integrator_params;  // the extra settings its info declares
    // The product of this iteration's scene pass, for an integrator with scene_passes
    // (RunScenePass below); empty for the others.
    std::string scene_product;
    SamplerKind sampler = SamplerKind::kOwenSobol;
    // A crop: the pixels whose own estimate is wanted; unset, every pixel. A pixel outside
    // it comes out 0 (every output) and its splats are dropped, but a splatting
    // integrator still traces its light paths, whose splats may land inside
    // (CameraSample::camera_work): the window's pixels equal a full render's bit for bit.
    std::optional<TileRect> camera_window;
};

struct RenderStats {
    uint64_t samples = 0;
    // A non-finite sample is a bug: it is left out of its pixel but counted and the first
    // one located, so that it is reported rather than silently dropped.
    uint64_t nonfinite_samples = 0;
    int64_t first_nonfinite_pixel_x = -1, first_nonfinite_pixel_y = -1, first_nonfinite_sample = -1;
    uint64_t light_paths = 0;      // light subpaths traced (one per pixel sample if the integrator splats)
    uint64_t rejected_splats = 0;  // splats that were not finite and >= 0: a bug if > 0
    // Rays the integrators traced (Scene::Intersect / Scene::Occluded calls, counted per
    // thread): closest-hit rays and shadow (any-hit) rays. AOV rays are not included.
    uint64_t closest_rays = 0, shadow_rays = 0;
};

// Optional per-pixel outputs besides the colour ("arbitrary output variables"), for
// denoisers and comparisons. Each pointer, if not null, receives tile.height * tile.width
// pixels, row-major; null outputs cost nothing. Per sample (the camera ray of the sample,
// clipped to the camera's range; a sample whose ray escapes counts as background):
//   albedo (3 floats): the directional albedo rho(wo) = integral of f |cos| of the first
//     surface that is not purely specular, one BSDF sample per pixel sample (exact for a
//     Lambertian: its reflectance). Ideal mirror / glass vertices before it are followed
//     by sampling their delta lobes, their throughput (without refraction's 1/eta^2
//     radiance scaling) multiplying the albedo. Background 0.
//   normal (3 floats): the first hit's world-space shading normal, turned toward the
//     camera ray's side of the surface. Background 0.
//   depth (1 float): the first hit's camera-space z (distance along the view axis, the
//     quantity the clipping range limits; not the Euclidean distance).
// Pixel values: albedo and normal are the mean over all samples; depth is the mean over
// the samples that hit something (the rgba alpha is that fraction), +inf if none did.
//   samples (1 float): the number of samples averaged into the pixel (= spp).
struct AOVBuffers {
    float* albedo = nullptr;
    float* normal = nullptr;
    float* depth = nullptr;
    float* samples = nullptr;
    bool any() const { return albedo || normal || depth || samples; }
};

// Variance batches of a splatting integrator, made in the same pass as the image: the
// samples [sample_start, sample_start + spp) are split into `count` contiguous ranges
// (VarianceBatchRange: near-equal sizes, the first spp % count ranges one sample longer;
// 1 <= count <= spp). Batch b's splats go to `splats` + b * camera.width * camera.height * 3
// (full frame) as well as to RenderTile's `splats`; each pixel's mean over batch b's samples goes to
// `rgb` + b * tile.height * tile.width * 3. Both are what RenderTile over batch b's range
// alone would write, bit for bit, and the image is the same as without batches.
struct VarianceBatches {
    uint32_t count = 0;
    int64_t* splats = nullptr;
    float* rgb = nullptr;
};

// Batch b of `count` over `spp` samples: {first sample offset, number of samples}.
inline std::pair<uint32_t, uint32_t> VarianceBatchRange(uint32_t spp, uint32_t count, uint32_t b) {
    const uint32_t base = spp / count, extra = spp % count;
    return {b * base + std::min(b, extra), base + (b < extra ? 1u : 0u)};
}

// Writes tile.height * tile.width * 4 floats (RGBA, row-major) to `rgba`: the mean of
// samples [sample_start, sample_start + spp). If `variance` is not null, also writes 3
// floats per pixel: the unbiased sample variance of each RGB channel over those samples
// (divide by spp for the variance of the mean).
//
// An integrator that splats (IntegratorInfo::splats: light, bdpt) also adds every light
// path's camera connections, anywhere in the frame, to
// `splats` (camera.width * camera.height * 3 int64, fixed point, see splat_film.h); `rgba`
// then holds only the light that reaches the camera unscattered. The final image is
// rgba + splats * pixel_count / (SplatScale(scene.splat_exponent()) * total light paths of all tiles).
RenderStats RenderTile(const Scene& scene, const Camera& camera, const RenderOptions& options, TileRect tile,
                       float* rgba, float* variance = nullptr, int64_t* splats = nullptr,
                       const AOVBuffers& aovs = {}, const VarianceBatches& batches = {});

// The scene-wide pass of iteration `iteration` of options.integrator (one with
// scene_passes), with options' seed, integrator_params and threads: the product every tile
// of that iteration is rendered with (RenderOptions::scene_product). Throws
// std::invalid_argument for an integrator without scene passes.
std::string RunScenePass(const Scene& scene, const RenderOptions& options, uint32_t iteration);

}  // namespace tessera
