// Renders a rectangle of the image into float RGBA. The result for a pixel depends only
// on (scene, camera, pixel, spp, seed, max_depth): the tile rectangle and thread count
// only decide who computes it.
#pragma once

#include <cstdint>
#include <vector>

#include "camera.h"
#include "scene.h"

namespace tessera {

struct RenderOptions {
    uint32_t spp = 16;
    uint32_t seed = 0;
    int max_depth = 64;
    int threads = 0;  // 0: all hardware threads
};

struct TileRect {
    uint32_t x0 = 0, y0 = 0, width = 0, height = 0;
};

struct RenderStats {
    uint64_t samples = 0;
    // A non-finite sample is a bug: it is left out of its pixel but counted and the first
    // one located, so that it is reported rather than silently dropped.
    uint64_t nonfinite_samples = 0;
    int64_t first_nonfinite_pixel_x = -1, first_nonfinite_pixel_y = -1, first_nonfinite_sample = -1;
};

// Writes tile.height * tile.width * 4 floats (RGBA, row-major) to `rgba`.
RenderStats RenderTile(const Scene& scene, const Camera& camera, const RenderOptions& options, TileRect tile,
                       float* rgba);

}  // namespace tessera
