// Time slices of the shutter for the integrators that merge camera paths with the light
// paths of a scene pass (vcm, sppm, photon, photon_direct; docs/motion.md).
//
// A merge joins a camera path at its instant with a light path at another. Merging across
// the whole shutter estimates, at a point, the light that reached that point at any time:
// a surface sliding through the point is lit there only for the part of the shutter it
// covers it (the sliding quad of motion_test renders 35 % dark). So a pass splits the
// shutter into K equal slices: light path i lives at an instant uniform in slice i mod K,
// and a camera path merges only with the paths of its own slice, each of them one of
// that slice's n_b paths (its power is Phi / n_b). What is left is a time kernel 1/K wide.
// A still scene has K = 1: one slice, the products and images it always had.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "integrator.h"
#include "scene.h"

namespace tessera {

// A light path keeps its slice in a byte.
constexpr uint32_t kMaxShutterSlices = 255;
// K_1 unless a job says otherwise: on motion_test's sliding quad 32 slices agree with
// path to 1 %, 8 leave 4.5 % (docs/motion.md).
constexpr float kDefaultShutterSlices = 32.f;

struct ShutterSlices {
    uint32_t count = 1;  // K >= 1

    // n_b: the paths i < n with i mod K == b.
    uint32_t Paths(uint32_t n, uint32_t b) const { return n / count + (b < n % count ? 1 : 0); }
    uint32_t SliceOfPath(uint32_t i) const { return i % count; }
    // Light path i's instant from its uniform u (LightPathInstant): uniform in its slice.
    float Instant(uint32_t i, float u) const { return count > 1 ? (float(SliceOfPath(i)) + u) / float(count) : u; }
    // Slice b's middle instant (one slice: mid-shutter), where a pass solved per slice
    // (radiosity) holds the scene.
    float Middle(uint32_t b) const { return (float(b) + 0.5f) / float(count); }
    // The slice holding this thread's instant: the camera sample's (ShutterTimeScope).
    uint32_t Current() const {
        if (count <= 1) return 0;
        const float t = std::clamp(tls_shutter_time, 0.f, 1.f) * float(count);
        return std::min(uint32_t(t), count - 1);
    }
};

// K for a pass of n paths: 1 when nothing moves, else ceil(K_1 * growth) within
// [1, min(255, n)]. A consistent integrator passes growth = i^((1 - alpha) / 2), so the
// slices narrow as its kernel radius r_i = r_1 i^((alpha - 1) / 2) shrinks: the time
// kernel's bias vanishes while the merging variance, O(K_i / r_i^2) per iteration, still
// averages away.
inline ShutterSlices PassShutterSlices(const Scene& scene, uint32_t first_slices, double growth, uint32_t paths) {
    if (!scene.has_motion()) return {};
    const double k = std::ceil(double(first_slices) * growth);
    return {uint32_t(std::clamp(k, 1.0, double(std::max<uint32_t>(1, std::min(kMaxShutterSlices, paths)))))};
}

// The `time_slices` setting of integrator `who`: K_1, a whole number from 1 to 255.
inline uint32_t TimeSlicesSetting(const IntegratorSettings& settings, const std::string& who,
                                  float fallback = kDefaultShutterSlices) {
    const float k = settings.Param("time_slices", fallback);
    if (!(k >= 1.f && k <= float(kMaxShutterSlices) && k == std::floor(k)))
        throw std::invalid_argument(who + " time_slices must be a whole number from 1 to 255");
    return uint32_t(k);
}

}  // namespace tessera
