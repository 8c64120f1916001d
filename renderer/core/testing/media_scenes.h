// Scene pieces shared by the media tests of the path tracer and the light tracer.
#pragma once

#include <cmath>
#include <string>
#include <vector>

#include "scene_helpers.h"

namespace tessera_test {

// Axis-aligned box [lo, hi], faces wound outward (a closed mesh whose inside is the box).
inline void AddOutwardBox(SceneDesc& d, Vec3 lo, Vec3 hi, uint32_t material) {
    Vec3 p[8];
    for (int i = 0; i < 8; ++i) p[i] = Vec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
    AddQuad(d, p[0], p[2], p[3], p[1], material);  // z = lo, normal -z
    AddQuad(d, p[4], p[5], p[7], p[6], material);  // z = hi, normal +z
    AddQuad(d, p[0], p[1], p[5], p[4], material);  // y = lo, normal -y
    AddQuad(d, p[2], p[6], p[7], p[3], material);  // y = hi, normal +y
    AddQuad(d, p[0], p[4], p[6], p[2], material);  // x = lo, normal -x
    AddQuad(d, p[1], p[3], p[7], p[5], material);  // x = hi, normal +x
}

// A pure medium interface (no BSDF) with medium `inside` inside it.
inline uint32_t AddInterface(SceneDesc& d, int32_t inside) {
    const uint32_t m = AddMaterial(d, Color(0.f), Color(0.f));
    d.materials[m].interface_only = true;
    d.materials[m].media.inside = inside;
    return m;
}

// An emitter of radiance Le facing the camera (z = -3) behind a slab z in [-2, -1] of
// absorbing medium sigma_a (albedo 0), thickness 1: head-on, every pixel reads Le e^(-sigma_a).
inline SceneDesc AbsorbingSlabBeforeEmitter(Color sigma_a, Color Le) {
    SceneDesc d;
    d.media.push_back({sigma_a, Color(0.f), 0.f});
    const float s = 100.f;
    AddQuad(d, {-s, -s, -3}, {s, -s, -3}, {s, s, -3}, {-s, s, -3}, AddMaterial(d, Color(0.f), Le));
    AddOutwardBox(d, {-50, -50, -2}, {50, 50, -1}, AddInterface(d, 0));
    return d;
}

inline float Ch(Color c, int k) { return k == 0 ? c.x : (k == 1 ? c.y : c.z); }

// Every pixel of an RGBA image within 1 % of `expected`, in every channel; else false with
// the first pixel that is not in `why`.
inline bool EveryPixelWithin1Percent(const std::vector<float>& img, Color expected, std::string* why) {
    for (size_t i = 0; i < img.size() / 4; ++i)
        for (int k = 0; k < 3; ++k)
            if (!(std::abs(img[4 * i + k] / Ch(expected, k) - 1.f) < 0.01f)) {
                *why = "pixel " + std::to_string(i) + " channel " + std::to_string(k) + ": " +
                       std::to_string(img[4 * i + k]) + " vs " + std::to_string(Ch(expected, k));
                return false;
            }
    return true;
}

}  // namespace tessera_test
