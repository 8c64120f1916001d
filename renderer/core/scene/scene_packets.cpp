// Closest-hit queries for a lane group of rays (integrators/path_lanes.h).
//
// Embree's packet interfaces trace 4 or 8 rays with one traversal of its 8-wide BVH.
// Measured on the Cornell boxes (docs/benchmarks/rays.md): 1.7x single rays' speed for
// coherent camera rays, 1.15x for incoherent bounce rays, and nothing (1.01x) for shadow
// segments, so only closest-hit queries go through packets here.
#include <embree3/rtcore_ray.h>

#include <stdexcept>

#include "ray_counters.h"
#include "scene.h"

namespace tessera {

namespace {

// Lane i of a packet as the single-ray record FinishClosest reads.
template <typename Packet>
RTCRayHit LaneHit(const Packet& p, int i) {
    RTCRayHit rh;
    rh.ray.org_x = p.ray.org_x[i];
    rh.ray.org_y = p.ray.org_y[i];
    rh.ray.org_z = p.ray.org_z[i];
    rh.ray.dir_x = p.ray.dir_x[i];
    rh.ray.dir_y = p.ray.dir_y[i];
    rh.ray.dir_z = p.ray.dir_z[i];
    rh.ray.tnear = p.ray.tnear[i];
    rh.ray.tfar = p.ray.tfar[i];
    rh.ray.time = p.ray.time[i];
    rh.ray.mask = p.ray.mask[i];
    rh.ray.id = p.ray.id[i];
    rh.ray.flags = p.ray.flags[i];
    rh.hit.Ng_x = p.hit.Ng_x[i];
    rh.hit.Ng_y = p.hit.Ng_y[i];
    rh.hit.Ng_z = p.hit.Ng_z[i];
    rh.hit.u = p.hit.u[i];
    rh.hit.v = p.hit.v[i];
    rh.hit.primID = p.hit.primID[i];
    rh.hit.geomID = p.hit.geomID[i];
    rh.hit.instID[0] = p.hit.instID[0][i];
    return rh;
}

}  // namespace

void Scene::IntersectPacket(int width, const bool* active, const Ray* rays, const float* t_min, const float* t_max,
                            SurfaceHit* hits, bool* found) const {
    // Inactive lanes are masked off by `valid`, their rays never traced.
    auto trace = [&]<int N, typename Packet>(auto intersect) {
        alignas(64) int valid[N];
        alignas(64) Packet p;
        for (int i = 0; i < N; ++i) {
            valid[i] = active[i] ? -1 : 0;
            p.ray.org_x[i] = rays[i].o.x;
            p.ray.org_y[i] = rays[i].o.y;
            p.ray.org_z[i] = rays[i].o.z;
            p.ray.dir_x[i] = rays[i].d.x;
            p.ray.dir_y[i] = rays[i].d.y;
            p.ray.dir_z[i] = rays[i].d.z;
            p.ray.tnear[i] = active[i] ? t_min[i] : 0.f;
            p.ray.tfar[i] = active[i] ? t_max[i] : -1.f;
            p.ray.time[i] = tls_shutter_time;
            p.ray.mask[i] = 0xFFFFFFFFu;
            p.ray.id[i] = 0;
            p.ray.flags[i] = 0;
            p.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
            p.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
            if (active[i]) ++tls_ray_counters.closest;
        }
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        intersect(valid, &context, &p);
        for (int i = 0; i < N; ++i) {
            found[i] = active[i] && p.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID;
            if (found[i]) found[i] = FinishClosest(rays[i], LaneHit(p, i), &hits[i]);
        }
    };
    switch (width) {
        case 8:
            trace.template operator()<8, RTCRayHit8>(
                [&](int* valid, RTCIntersectContext* c, RTCRayHit8* p) { rtcIntersect8(valid, scene_, c, p); });
            return;
        case 4:
            trace.template operator()<4, RTCRayHit4>(
                [&](int* valid, RTCIntersectContext* c, RTCRayHit4* p) { rtcIntersect4(valid, scene_, c, p); });
            return;
        case 1:
            found[0] = active[0] && IntersectClosest(rays[0], t_min[0], t_max[0], &hits[0]);
            return;
        default:
            throw std::invalid_argument("packet width must be 1, 4 or 8");
    }
}

}  // namespace tessera
