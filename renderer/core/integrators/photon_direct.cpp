// Direct light by photon density estimation: the first step of a photon map (Jensen 2001),
// and the proof that scene-wide passes work end to end (docs/integrators.md, "Scene-wide
// passes"). Each iteration's scene pass traces `photons` photons from the lights, chosen by
// power, and keeps where each first lands on a non-specular surface, with its direction and
// flux. A tile reads that product: at the first surface the camera sees,
//     L = Le + sum over photons within `radius` of f(wo, wi_p) * flux_p / (pi radius^2),
// a disk kernel. Only direct light: no bounce after the first hit on either side, so
// mirrors and glass seen directly are black, and lights at infinity seen directly are not
// drawn (they still light the scene). Biased by the kernel: the estimate is the mean
// irradiance over the disk around the shading point, not the point's.
//
// Every iteration draws fresh photons (its own sampler streams), so averaging iterations
// averages independent photon maps: the farm repeats scene pass -> tile passes per pass.
// The film weighs an iteration by its samples, so iteration k traces as many batches of
// `photons` as it has shares of samples (IterationBatches, as sppm does), and even a
// fixed-spp render runs in passes (its registry entry's iteration_cap): the photon map's
// noise then falls as 1 / spp. With one map per render it stayed where one map left it,
// whatever the samples: in the integrator matrix, a region's standard error was 0.44 to
// 0.80 % at 16 spp and at 8192 alike (issue 46).
// With motion the photons live in `time_slices` slices of the shutter and a camera sample
// sees its own slice's (shutter_slices.h).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "integrator.h"
#include "point_hash_grid.h"
#include "shutter_slices.h"

namespace tessera {

namespace {

constexpr float kPi = 3.14159265358979323846f;
// The default kernel radius as a fraction of the scene's bounding diameter (unit-free).
constexpr float kDefaultRadiusOfDiameter = 0.01f;
constexpr float kDefaultPhotons = 200000.f;
// The most photons one iteration's product holds (40 bytes each, stored in Redis: 80 MB):
// the passes stop doubling at the power of two of batches below it (IterationShareCap).
constexpr uint64_t kMaxPhotonsPerIteration = 2'000'000;
// Photon streams are keyed by the iteration in a pixel-index range no image reaches
// (2^40 pixels), so they are independent of every camera sample's stream.
constexpr uint64_t kPhotonStreamBase = uint64_t(1) << 40;
constexpr uint32_t kPhotonStream = 3;

// The product: a header, then per photon its position, the direction it came from (toward
// the light), its flux (9 little-endian floats) and its time slice (a byte and 3 zero
// bytes). Opaque to everything outside this file.
constexpr char kMagic[4] = {'T', 'P', 'D', '2'};
struct Header {
    char magic[4];
    uint32_t count;
    uint32_t iteration;
    uint32_t traced;       // photons traced, including those that landed nowhere useful
    uint32_t time_slices;  // K: 1 in a still scene
};
struct Photon {
    float p[3], wi[3], flux[3];
    uint8_t time_slice;
    uint8_t zero[3];  // the product's bytes are all written
};
static_assert(sizeof(Photon) == 40);

class PhotonDirectIntegrator final : public Integrator {
public:
    PhotonDirectIntegrator(uint32_t photons, float radius, uint32_t time_slices, const std::string& product)
        : photons_(photons), radius_(radius), time_slices_(time_slices) {
        if (!product.empty()) Load(product);
    }

    static const IntegratorInfo& Info() {
        static const IntegratorInfo info{
            .name = "photon_direct",
            .description = "direct light by photon density estimation (a photon map's first step; "
                           "scene-wide photon pass per iteration)",
            .scene_passes = true,
            // Every tile of an iteration reads the same photons: the image advances together.
            .stop_per_tile = false,
            .traces_light_paths = true,
            .params = {{"photons", "photons per batch; an iteration traces one batch per share of samples "
                                   "(default 200000)"},
                       {"radius", "density-estimation disk radius in scene units (default: a hundredth "
                                  "of the scene's bounding diameter)"},
                       {"time_slices", "with motion blur, the slices of the shutter; a camera sample sees "
                                       "the photons of its own slice (default 32)"}},
            .blind_to = {{"L D D+ E", "direct light only: a photon is kept where it first lands"},
                         {"L S+ E", "a camera ray ends at the first surface it hits, smooth or not"}},
            .iteration_cap = {"photons", kDefaultPhotons, "", double(kMaxPhotonsPerIteration)},
        };
        return info;
    }
    const IntegratorInfo& info() const override { return Info(); }

    std::string RunScenePass(const Scene& scene, uint32_t seed, uint32_t iteration, int threads) const override {
        const auto [first, count] = IterationBatches(iteration, IterationShareCap(photons_, kMaxPhotonsPerIteration));
        const uint64_t total = count * photons_;
        std::vector<Photon> slot(total);
        std::vector<uint8_t> kept(total, 0);
        const LightSampler& lights = scene.light_sampler();
        const ShutterSlices slices = PassShutterSlices(scene, time_slices_, 1.0, photons_);
        auto trace = [&](const tbb::blocked_range<uint64_t>& range) {
            for (uint64_t k = range.begin(); k != range.end(); ++k) {
                if (lights.empty()) return;
                // Photon i of batch j: a batch's streams do not depend on the iteration
                // that holds it.
                const uint64_t j = first + k / photons_;
                const uint32_t i = uint32_t(k % photons_);
                PixelSampler sampler(seed, kPhotonStreamBase + j, i, kPhotonStream);
                const ShutterTimeScope instant(slices.Instant(i, LightPathInstant(scene, sampler)));
                float pmf = 0.f;
                const uint32_t light = lights.Sample(sampler.Get1D(), &pmf);
                const Vec2 u_pos = sampler.Get2D(), u_dir = sampler.Get2D();
                const float u_side = sampler.Get1D();
                EmissionSample es;
                if (!scene.SampleEmission(light, u_pos, u_dir, u_side, &es) || !(pmf > 0.f)) continue;
                const Ray ray{es.on_surface ? OffsetRayOrigin(es.p, es.p_error, es.n, es.wo) : es.p, es.wo};
                SurfaceHit hit;
                if (!scene.Intersect(ray, &hit)) continue;
                const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Importance);
                if (bsdf.Flags() == kBSDFUnset || !bsdf.IsNonSpecular()) continue;
                const uint32_t slice = slices.SliceOfPath(i);
                // The iteration averages its batches.
                const Color flux = es.beta * ((1.f / (float(slices.Paths(photons_, slice)) * float(count))) / pmf);
                slot[k] = Photon{{hit.p.x, hit.p.y, hit.p.z},
                                 {-ray.d.x, -ray.d.y, -ray.d.z},
                                 {flux.x, flux.y, flux.z},
                                 uint8_t(slice),
                                 {0, 0, 0}};
                kept[k] = 1;
            }
        };
        // Each photon writes its own slot and the slots are compacted in index order, so
        // the product does not depend on the thread count.
        tbb::task_arena arena(threads > 0 ? threads : tbb::this_task_arena::max_concurrency());
        arena.execute([&] { tbb::parallel_for(tbb::blocked_range<uint64_t>(0, total, 1024), trace); });
        std::vector<Photon> out;
        for (uint64_t k = 0; k < total; ++k)
            if (kept[k]) out.push_back(slot[k]);
        Header h{};
        std::memcpy(h.magic, kMagic, 4);
        h.count = uint32_t(out.size());
        h.iteration = iteration;
        h.traced = uint32_t(total);  // at most max(photons, kMaxPhotonsPerIteration)
        h.time_slices = slices.count;
        std::string bytes(sizeof(Header) + out.size() * sizeof(Photon), '\0');
        std::memcpy(bytes.data(), &h, sizeof(Header));
        if (!out.empty()) std::memcpy(bytes.data() + sizeof(Header), out.data(), out.size() * sizeof(Photon));
        return bytes;
    }

    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler&, SplatFilm&,
                      IntegratorCounters*) const override {
        PathSample result;
        SurfaceHit hit;
        if (!scene.Intersect(cs.ray, &hit, cs.t_min, cs.t_max)) return result;
        result.alpha = 1.f;
        const Vec3 wo = -cs.ray.d;
        if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) result.radiance += scene.Emitted(e, hit, wo);
        const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Radiance);
        if (bsdf.Flags() == kBSDFUnset || !bsdf.IsNonSpecular()) return result;
        const Frame frame = Frame::FromZ(hit.ns);
        const Vec3 wo_local = frame.ToLocal(wo);
        Color sum(0.f);
        grid_.ForEachNear(hit.p, slices_.Current(), [&](const Photon& ph) {
            const Vec3 wi(ph.wi[0], ph.wi[1], ph.wi[2]);
            const Vec3 wi_local = frame.ToLocal(wi);
            if (!SidesAgree(wo, wi, hit.ng, wo_local, wi_local)) return;
            sum += bsdf.f(wo_local, wi_local) * Color(ph.flux[0], ph.flux[1], ph.flux[2]);
        });
        result.radiance += sum / (kPi * radius_ * radius_);
        return result;
    }

private:
    // Parses a product into a hash grid of cells one radius wide.
    void Load(const std::string& product) {
        Header h;
        if (product.size() < sizeof(Header) || std::memcmp(product.data(), kMagic, 4) != 0)
            throw std::invalid_argument("photon_direct: the scene product is not a photon map");
        std::memcpy(&h, product.data(), sizeof(Header));
        if (product.size() != sizeof(Header) + size_t(h.count) * sizeof(Photon))
            throw std::invalid_argument("photon_direct: the scene product has the wrong size");
        if (h.time_slices < 1 || h.time_slices > kMaxShutterSlices)
            throw std::invalid_argument("photon_direct: the scene product's time slices are out of range");
        std::vector<Photon> photons(h.count);
        if (h.count) std::memcpy(photons.data(), product.data() + sizeof(Header), h.count * sizeof(Photon));
        slices_ = ShutterSlices{h.time_slices};
        grid_ = PointHashGrid<Photon>(photons, radius_);
    }

    uint32_t photons_;
    float radius_;
    uint32_t time_slices_;  // K
    ShutterSlices slices_;  // the product's
    PointHashGrid<Photon> grid_;
};

}  // namespace

IntegratorEntry PhotonDirectIntegratorEntry() {
    return {PhotonDirectIntegrator::Info,
            [](const IntegratorSettings& s, const Scene& scene) -> std::unique_ptr<Integrator> {
                const float photons = s.Param("photons", kDefaultPhotons);
                if (!(photons >= 1.f && photons <= 1e7f && photons == std::floor(photons)))
                    throw std::invalid_argument("photon_direct photons must be a whole number from 1 to 1e7 (a product of 40 bytes a photon, kept in Redis)");
                const float radius = s.Param("radius", kDefaultRadiusOfDiameter * 2.f * scene.scene_radius());
                if (!(radius > 0.f && std::isfinite(radius)))
                    throw std::invalid_argument("photon_direct radius must be a finite number > 0");
                return std::make_unique<PhotonDirectIntegrator>(uint32_t(photons), radius,
                                                                TimeSlicesSetting(s, "photon_direct"), s.scene_product);
            }};
}

}  // namespace tessera
