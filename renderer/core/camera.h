// Pinhole camera. Pixel (0, 0) is the top-left of the image; the camera looks along
// `forward` (USD: the camera's local -Z) with `up` its local +Y.
#pragma once

#include <cstdint>

#include "math.h"

namespace tessera {

struct Camera {
    Vec3 origin;
    Vec3 right, up, forward;        // orthonormal, world space
    float tan_half_width = 0.5f;    // tan(horizontal fov / 2), aperture already fit to the image
    float tan_half_height = 0.5f;
    uint32_t width = 1, height = 1; // full image, not the tile

    // (px, py) in continuous raster coordinates, [0, width) x [0, height).
    Ray GenerateRay(float px, float py) const {
        float sx = (2.f * px / float(width) - 1.f) * tan_half_width;
        float sy = (1.f - 2.f * py / float(height)) * tan_half_height;
        return {origin, Normalize(forward + right * sx + up * sy)};
    }
};

}  // namespace tessera
