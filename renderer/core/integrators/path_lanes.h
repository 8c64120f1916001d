// The path tracer over a regenerating lane group: up to 8 pixel samples' paths advance
// together, one vertex per step, their closest-hit rays traced as one Embree packet
// (rtcIntersect8, rtcIntersect4 on CPUs without AVX2). A lane whose path ends takes the
// batch's next pixel sample at once, so long paths do not idle the others. Each path's
// state lives in the group's own arrays on the stack (a megakernel over lanes, not a
// wavefront of ray queues in memory).
//
// Each lane runs PathIntegrator's Lambertian kernel's arithmetic in its order on its own
// pixel sample's sampler stream: an image is the same to the bit whatever the lane width,
// the grouping of samples into lanes, the tile or the thread count (tested in
// path_lanes_test.cpp), and the scalar kernel stays the reference.
#pragma once

#include <cstddef>

#include "integrator.h"

namespace tessera {

// The lane width for this CPU: 8 with AVX2, else 4 (chosen at run time), for when the
// lane kernel becomes the default (it is opt-in: docs/benchmarks/simd-kernel.md).
int DefaultLaneWidth();

// The scenes the lane kernel renders: every material Lambertian, and rays that go straight
// to Embree (no cutouts, no normal maps) through a still scene. Any light kind.
bool LaneKernelApplies(const Scene& scene);

// The estimates of n pixel samples through lane groups of `width` (1, 4 or 8) lanes,
// PathIntegrator's Trace<DiffuseBSDF> to the bit for each.
void TraceLanes(const Scene& scene, int width, int max_depth, int roulette_depth, BatchSample* samples,
                PathSample* out, size_t n);

}  // namespace tessera
