// Per-thread counts of the Embree queries the renderer makes (rtcIntersect1 and
// rtcOccluded1 calls through Scene). Monotonic per thread: a reader takes the difference
// of two snapshots on the same thread, so counting needs no atomics and no sharing.
#pragma once

#include <cstdint>

namespace tessera {

struct RayCounters {
    uint64_t closest = 0;  // closest-hit queries (rtcIntersect1)
    uint64_t shadow = 0;   // occlusion queries (rtcOccluded1)
};

inline thread_local RayCounters tls_ray_counters;

}  // namespace tessera
