// Photon maps for the photon-merging integrators (`photon`, `sppm`): tracing photon paths
// from the lights, and a hash grid over their landings that travels as a scene pass's
// product (docs/integrators.md, "Photon maps").
//
// A product holds one or more maps. Each map is a hash grid of cubic cells one `cell`
// wide: the photons sorted by bucket, and each bucket's start, so that a tile parses it
// with a few copies and finds every photon within its own kernel radius (<= cell) in the
// 27 cells around a point. A photon is 27 bytes: its position (3 floats), its kernel
// radius (a float), the direction it came from (octahedral, 2 x 16 bits), its power
// relative to the map's largest (3 half floats) and its time slice (a byte); the bucket
// table adds 4-8 bytes per photon. With motion a map's photon paths live in K slices of
// the shutter (shutter_slices.h), the grid keys cells by slice, and a lookup sees only
// the slice of the camera sample's instant. Everything is a pure function of the photons,
// so the bytes are too.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "bsdf.h"
#include "math.h"
#include "point_hash_grid.h"
#include "scene.h"
#include "shutter_slices.h"

namespace tessera {

struct StoredPhoton {
    Vec3 p;
    Vec3 wi;  // unit, toward where the photon came from
    Color power;
    float radius = 0.f;  // its kernel's radius (SPPM shrinks it from batch to batch)
    uint8_t time_slice = 0;  // the shutter slice its path lives in
};

// Which landings of a photon path are kept.
struct PhotonFilter {
    // Scatterings before the landing: 0 keeps light arriving straight from the light.
    int min_bounces = 0;
    // Keep only landings whose every earlier scattering was specular (L S+ D: caustics);
    // a path ends at its first non-specular surface then.
    bool caustic_only = false;
};

// Traces `paths` photon paths from the lights (chosen by power) and returns their kept
// landings on non-specular surfaces, in path order. Path i lives in time slice b = i mod K
// of `slices`, and its photons carry power Phi / n_b (n_b = paths, K = 1, without motion).
// Path i draws from its own sampler stream keyed by (seed, stream, i), so the result does
// not depend on `threads`. Paths scatter by BSDF sampling (Importance mode) with Russian
// roulette, up to max_depth scatterings. A fraction `specular_aim` of the photons (in
// [0, 1]) leaves toward the scene's delta surfaces (Scene::delta_surfaces_radius; none: no
// effect), weighted so the expectation is the same: caustics get that many more photons.
std::vector<StoredPhoton> TracePhotons(const Scene& scene, uint32_t seed, uint64_t stream, uint32_t paths,
                                       int max_depth, const PhotonFilter& filter, ShutterSlices slices, int threads,
                                       float specular_aim = 0.f);

// One map of a product, parsed. Lookups need radius <= cell().
class PhotonGrid {
public:
    // Sorts photons (of slices < slices.count) into a grid of cells `cell` wide (>= every
    // photon's radius) and appends its bytes to `out`.
    static void Serialize(const std::vector<StoredPhoton>& photons, float cell, ShutterSlices slices,
                          std::string* out);
    // Parses one map at data[*offset...], advancing *offset; throws std::invalid_argument
    // (naming `who`) on a malformed product.
    void Parse(std::string_view data, size_t* offset, std::string_view who);

    float cell() const { return cell_; }
    uint32_t size() const { return uint32_t(power_.size()); }
    ShutterSlices slices() const { return slices_; }

    // Calls f(photon, squared distance) for every photon of time slice `slice` whose kernel
    // covers p (each once).
    template <typename F>
    void ForEachCovering(Vec3 p, uint32_t slice, F&& f) const {
        if (power_.empty()) return;
        std::array<uint32_t, 27> buckets;
        const int n = NeighbourBuckets(CellOf(p.x), CellOf(p.y), CellOf(p.z), slice, buckets_, &buckets);
        for (int b = 0; b < n; ++b)
            for (uint32_t k = start_[buckets[b]]; k < start_[buckets[b] + 1]; ++k) {
                if (slice_[k] != slice) continue;  // another slice's cell in the same bucket
                const Vec3 q(pos_[3 * k], pos_[3 * k + 1], pos_[3 * k + 2]);
                const float d2 = LengthSquared(q - p);
                if (d2 >= radius_[k] * radius_[k]) continue;
                f(StoredPhoton{q, Direction(k), Power(k), radius_[k]}, d2);
            }
    }

private:
    int CellOf(float x) const;
    Vec3 Direction(uint32_t k) const;
    Color Power(uint32_t k) const;

    float cell_ = 1.f;
    float power_scale_ = 0.f;
    uint32_t buckets_ = 1;
    ShutterSlices slices_;
    std::vector<uint32_t> start_{0, 0};
    std::vector<float> pos_, radius_;
    std::vector<uint8_t> slice_;
    std::vector<std::array<uint16_t, 2>> dir_;
    std::vector<std::array<uint16_t, 3>> power_;  // IEEE half floats
};

// The density-estimation kernels, normalised over the disk of radius r in the tangent
// plane: K(d) integrates to 1 over it.
enum class PhotonKernel {
    kDisk,          // 1 / (pi r^2)
    kEpanechnikov,  // 2 / (pi r^2) (1 - d^2 / r^2)
};

// Radiance reflected toward wo by the BSDF's non-delta lobes at a surface point, estimated
// from the photons whose kernel covers it: sum f(wo, wi_p) Phi_p K_{r_p}(|x_p - x|), each
// photon with its own radius r_p, the photons of the current instant's time slice.
inline Color EstimateRadiance(const PhotonGrid& map, const SurfaceHit& hit, const BSDF& bsdf, const Frame& frame,
                              Vec3 wo, PhotonKernel kernel) {
    const Vec3 wo_local = frame.ToLocal(wo);
    Color sum(0.f);
    map.ForEachCovering(hit.p, map.slices().Current(), [&](const StoredPhoton& ph, float d2) {
        const Vec3 wi_local = frame.ToLocal(ph.wi);
        if (!SidesAgree(wo, ph.wi, hit.ng, wo_local, wi_local)) return;
        const float r2 = ph.radius * ph.radius;
        const float k = kernel == PhotonKernel::kDisk ? 1.f : 2.f * (1.f - d2 / r2);
        sum += bsdf.f(wo_local, wi_local) * ph.power * (k / (kPi * r2));
    });
    return sum;
}

// A product: a magic tag, the iteration, and the maps.
std::string PhotonProductBegin(std::string_view magic4, uint32_t iteration, uint32_t maps);
// Checks the tag and map count and returns the iteration; *offset points past the header.
uint32_t PhotonProductParse(std::string_view data, std::string_view magic4, uint32_t maps, size_t* offset,
                            std::string_view who);

}  // namespace tessera
