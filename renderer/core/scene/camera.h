// Camera: perspective (a pinhole, or a thin lens for depth of field) or orthographic.
// Pixel (0, 0) is the top-left of the image; the camera looks along `forward` (USD: the
// camera's local -Z) with `up` its local +Y.
//
// Image window: raster (px, py) maps to window coordinates
//   sx = (2 px / width - 1) tan_half_width + shift_x,  sy = (1 - 2 py / height) tan_half_height + shift_y,
// on the image plane at distance 1 (perspective: the ray direction is forward + sx right +
// sy up) or in scene units on the film plane through `origin` (orthographic: every ray
// leaves origin + sx right + sy up along forward). The shifts are USD's aperture offsets:
// an off-centre window, as a shift lens or a tiled render makes.
//
// Orthographic importance: the rays are a parallel beam, W_e = delta(w - forward) / A with
// A the window's area (scene units^2), so a pixel measures mean radiance as for a pinhole.
// A surface point p is seen by exactly one film point, its projection, and its connection
// carries |cos_p| / A with no 1/d^2 (ConnectToCamera); densities from the camera are per
// unit film area, converted to the next vertex by its cosine alone (bdpt's ConvertDensity).
//
// Thin lens: a ray leaves a point on the lens disk (radius lens_radius, centred on
// origin, perpendicular to forward) toward the point of the focus plane (at focal_distance
// along forward) that the pinhole ray through the same raster position meets. Points on
// the focus plane are sharp. lens_radius = 0 is the pinhole.
//
// Clipping: primary visibility only sees depths (distance along forward) in [near, far].
#pragma once

#include <algorithm>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "math.h"
#include "sampling.h"

namespace tessera {

enum class Projection : uint8_t { kPerspective, kOrthographic };

// Where a moving camera is at one instant: its position and orthonormal frame.
struct CameraPose {
    Vec3 origin, right, up, forward;
};

struct Camera {
    Vec3 origin;
    Vec3 right, up, forward;        // orthonormal, world space
    // Half the image window, already fit to the image: perspective, tan(fov / 2);
    // orthographic, half the view's extent in scene units.
    float tan_half_width = 0.5f;
    float tan_half_height = 0.5f;
    uint32_t width = 1, height = 1; // full image, not the tile
    float lens_radius = 0.f;        // perspective only
    float focal_distance = 1.f;
    float near = 0.f, far = std::numeric_limits<float>::infinity();
    float shift_x = 0.f, shift_y = 0.f;  // the window's centre, in the window's units
    Projection projection = Projection::kPerspective;
    // Camera motion: the pose at T >= 2 instants evenly spaced over the shutter (step j at
    // shutter time j / (T - 1)); none for a camera that stands still. Every ray of one
    // camera sample, and every connection to the camera made for it, uses At(its instant).
    std::shared_ptr<const std::vector<CameraPose>> motion;

    bool Moves() const { return motion && motion->size() >= 2; }

    // The camera at shutter time t in [0, 1], standing still: the poses interpolated
    // linearly between steps, the frame made orthonormal again from the interpolated
    // forward (Gram-Schmidt), so a turn between two close steps stays a rotation.
    Camera At(float t) const {
        Camera c = *this;
        c.motion.reset();
        if (!Moves()) return c;
        const std::vector<CameraPose>& poses = *motion;
        const float s = std::clamp(t, 0.f, 1.f) * float(poses.size() - 1);
        const size_t k = std::min(size_t(s), poses.size() - 2);
        const float f = s - float(k);
        const CameraPose& a = poses[k];
        const CameraPose& b = poses[k + 1];
        c.origin = a.origin * (1.f - f) + b.origin * f;
        c.forward = Normalize(a.forward * (1.f - f) + b.forward * f);
        const Vec3 r = a.right * (1.f - f) + b.right * f;
        c.right = Normalize(r - c.forward * Dot(r, c.forward));
        c.up = Cross(c.right, c.forward);
        return c;
    }

    bool HasLens() const { return lens_radius > 0.f && !IsOrthographic(); }
    bool IsOrthographic() const { return projection == Projection::kOrthographic; }

    Vec3 LensPoint(Vec2 u) const {
        if (!HasLens()) return origin;
        Vec2 d = SampleUniformDiskConcentric(u);
        return origin + (right * d.x + up * d.y) * lens_radius;
    }

    // (px, py) in continuous raster coordinates, [0, width) x [0, height); u_lens picks the
    // lens point (unused for a pinhole and orthographic cameras).
    Ray GenerateRay(float px, float py, Vec2 u_lens = {0.5f, 0.5f}) const {
        float sx = (2.f * px / float(width) - 1.f) * tan_half_width + shift_x;
        float sy = (1.f - 2.f * py / float(height)) * tan_half_height + shift_y;
        if (IsOrthographic()) return {origin + right * sx + up * sy, forward};
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

    // Area of the image window: at distance 1 for perspective (the importance is
    // We = 1 / (A a cos^4 theta) per unit lens area a, a point for the pinhole, so a pixel
    // measures mean radiance), in scene units^2 for orthographic (see the header).
    float ImagePlaneArea() const { return 4.f * tan_half_width * tan_half_height; }

    // Raster position of the ray leaving lens point `p_lens` along unit `dir`; false if it
    // misses the image. Writes cos(theta) to the optical axis. Orthographic: `p_lens` is the
    // film point (the ray's origin) and fixes the position; `dir` only has to face forward.
    bool Project(Vec3 p_lens, Vec3 dir, float* px, float* py, float* cos_theta) const {
        float c = Dot(dir, forward);
        if (!(c > 0.f)) return false;
        float sx, sy;
        if (IsOrthographic()) {
            const Vec3 v = p_lens - origin;
            sx = (Dot(v, right) - shift_x) / tan_half_width;
            sy = (Dot(v, up) - shift_y) / tan_half_height;
        } else {
            Vec3 v = dir;  // the pinhole ray with the same raster position
            if (HasLens()) v = (p_lens + dir * (focal_distance / c)) - origin;
            float depth = Dot(v, forward);
            if (!(depth > 0.f)) return false;
            sx = (Dot(v, right) / depth - shift_x) / tan_half_width;
            sy = (Dot(v, up) / depth - shift_y) / tan_half_height;
        }
        *px = (sx + 1.f) * 0.5f * float(width);
        *py = (1.f - sy) * 0.5f * float(height);
        *cos_theta = c;
        return *px >= 0.f && *px < float(width) && *py >= 0.f && *py < float(height);
    }
    bool Project(Vec3 dir, float* px, float* py, float* cos_theta) const {
        return Project(origin, dir, px, py, cos_theta);
    }

    // Solid-angle density of GenerateRay's direction from lens point p_lens (uniform over
    // the image plane). Orthographic: the direction is a delta, and this is the density of
    // the film point per unit area, 1 / A (bdpt converts it without 1/d^2).
    float PdfDirection(Vec3 p_lens, Vec3 dir) const {
        float px, py, c;
        if (!Project(p_lens, dir, &px, &py, &c)) return 0.f;
        if (IsOrthographic()) return 1.f / ImagePlaneArea();
        return 1.f / (ImagePlaneArea() * c * c * c);
    }
    float PdfDirection(Vec3 dir) const { return PdfDirection(origin, dir); }
};

}  // namespace tessera
