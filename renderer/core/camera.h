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

    // Area of the image plane at distance 1. The pinhole's importance is
    // We = 1 / (A cos^4 theta), normalised so a pixel measures mean radiance.
    float ImagePlaneArea() const { return 4.f * tan_half_width * tan_half_height; }

    // Raster position of the unit direction `dir` leaving the pinhole; false if outside the
    // image. Writes cos(theta) to the optical axis.
    bool Project(Vec3 dir, float* px, float* py, float* cos_theta) const {
        float c = Dot(dir, forward);
        if (!(c > 0.f)) return false;
        float sx = Dot(dir, right) / (c * tan_half_width);
        float sy = Dot(dir, up) / (c * tan_half_height);
        *px = (sx + 1.f) * 0.5f * float(width);
        *py = (1.f - sy) * 0.5f * float(height);
        *cos_theta = c;
        return *px >= 0.f && *px < float(width) && *py >= 0.f && *py < float(height);
    }

    // Solid-angle density of GenerateRay's direction (uniform over the image plane).
    float PdfDirection(Vec3 dir) const {
        float px, py, c;
        if (!Project(dir, &px, &py, &c)) return 0.f;
        return 1.f / (ImagePlaneArea() * c * c * c);
    }
};

}  // namespace tessera
