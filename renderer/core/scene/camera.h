// Perspective camera: a pinhole, or a thin lens for depth of field. Pixel (0, 0) is the
// top-left of the image; the camera looks along `forward` (USD: the camera's local -Z)
// with `up` its local +Y.
//
// Thin lens: a ray leaves a point on the lens disk (radius lens_radius, centred on
// origin, perpendicular to forward) toward the point of the focus plane (at focal_distance
// along forward) that the pinhole ray through the same raster position meets. Points on
// the focus plane are sharp. lens_radius = 0 is the pinhole.
//
// Clipping: primary visibility only sees depths (distance along forward) in [near, far].
#pragma once

#include <cstdint>
#include <limits>

#include "math.h"
#include "sampling.h"

namespace tessera {

struct Camera {
    Vec3 origin;
    Vec3 right, up, forward;        // orthonormal, world space
    float tan_half_width = 0.5f;    // tan(horizontal fov / 2), aperture already fit to the image
    float tan_half_height = 0.5f;
    uint32_t width = 1, height = 1; // full image, not the tile
    float lens_radius = 0.f;
    float focal_distance = 1.f;
    float near = 0.f, far = std::numeric_limits<float>::infinity();

    bool HasLens() const { return lens_radius > 0.f; }

    Vec3 LensPoint(Vec2 u) const {
        if (!HasLens()) return origin;
        Vec2 d = SampleUniformDiskConcentric(u);
        return origin + (right * d.x + up * d.y) * lens_radius;
    }

    // (px, py) in continuous raster coordinates, [0, width) x [0, height); u_lens picks the
    // lens point (unused for a pinhole).
    Ray GenerateRay(float px, float py, Vec2 u_lens = {0.5f, 0.5f}) const {
        float sx = (2.f * px / float(width) - 1.f) * tan_half_width;
        float sy = (1.f - 2.f * py / float(height)) * tan_half_height;
        Vec3 pinhole_dir = forward + right * sx + up * sy;  // length 1 along forward
        if (!HasLens()) return {origin, Normalize(pinhole_dir)};
        Vec3 focus = origin + pinhole_dir * focal_distance;
        Vec3 lens = LensPoint(u_lens);
        return {lens, Normalize(focus - lens)};
    }

    // Parameter range along a primary ray with unit direction d that keeps depth in
    // [near, far].
    void ClipRange(Vec3 d, float* t_min, float* t_max) const {
        float c = Dot(d, forward);
        *t_min = c > 0.f ? near / c : 0.f;
        *t_max = c > 0.f ? far / c : std::numeric_limits<float>::infinity();
    }

    // Area of the image plane at distance 1. The importance is We = 1 / (A a cos^4 theta)
    // per unit lens area a (a point for the pinhole), so a pixel measures mean radiance.
    float ImagePlaneArea() const { return 4.f * tan_half_width * tan_half_height; }

    // Raster position of the ray leaving lens point `p_lens` along unit `dir`; false if it
    // misses the image. Writes cos(theta) to the optical axis.
    bool Project(Vec3 p_lens, Vec3 dir, float* px, float* py, float* cos_theta) const {
        float c = Dot(dir, forward);
        if (!(c > 0.f)) return false;
        Vec3 v = dir;  // the pinhole ray with the same raster position
        if (HasLens()) v = (p_lens + dir * (focal_distance / c)) - origin;
        float depth = Dot(v, forward);
        if (!(depth > 0.f)) return false;
        float sx = Dot(v, right) / (depth * tan_half_width);
        float sy = Dot(v, up) / (depth * tan_half_height);
        *px = (sx + 1.f) * 0.5f * float(width);
        *py = (1.f - sy) * 0.5f * float(height);
        *cos_theta = c;
        return *px >= 0.f && *px < float(width) && *py >= 0.f && *py < float(height);
    }
    bool Project(Vec3 dir, float* px, float* py, float* cos_theta) const {
        return Project(origin, dir, px, py, cos_theta);
    }

    // Solid-angle density of GenerateRay's direction from lens point p_lens (uniform over
    // the image plane).
    float PdfDirection(Vec3 p_lens, Vec3 dir) const {
        float px, py, c;
        if (!Project(p_lens, dir, &px, &py, &c)) return 0.f;
        return 1.f / (ImagePlaneArea() * c * c * c);
    }
    float PdfDirection(Vec3 dir) const { return PdfDirection(origin, dir); }
};

}  // namespace tessera
