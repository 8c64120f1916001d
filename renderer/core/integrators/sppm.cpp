// Progressive photon mapping, consistent and exact on the farm: Knaus and Zwicker's
// probabilistic formulation (2011) with a global radius schedule (docs/integrators.md,
// "sppm").
//
// The image is the average of independent photon-mapping estimates, batch j of `photons`
// photon paths density-estimated with a disk kernel of radius
//     r_j = r_1 j^((alpha - 1) / 2),
// so the kernel's bias (O(r_j^2)) and the variance of the average (O(1 / (J r_J^2))) both
// go to 0 as the number of batches J grows. The radius depends on the batch alone, never
// on a pixel's own history (the per-pixel statistics of Hachisuka and Jensen's SPPM),
// so each iteration is a pure function of (scene, settings, seed, iteration) whatever the
// tiling, and the farm's image is the local one bit for bit.
//
// One iteration is one scene pass followed by one pass of every tile. The film weighs an
// iteration by its samples, and passes double (pass 0 and 1 hold the first pass's count,
// pass k >= 1 2^(k-1) times it: tessera.protocol.pass_range), so iteration k holds as many
// batches, 2^(k-1), each photon with its batch's radius: every batch then has the same
// weight in the image, as in Knaus and Zwicker's average. The camera side follows delta
// lobes to the visible points, adds direct light there by next event estimation, and the
// photons (after at least one scattering) for the rest.
//
// Motion blur (docs/motion.md): iteration k's photon paths live in K_k time slices of the
// shutter (shutter_slices.h), K_k = ceil(K_1 j^((1 - alpha) / 2)) for its first batch j,
// narrowing with the radius, and a visible point sees only its own instant's slice.
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "direct_light.h"
#include "integrator.h"
#include "photon_map.h"
#include "visible_point.h"

namespace tessera {

namespace {

constexpr float kDefaultPhotons = 100000.f;
constexpr float kDefaultRadiusOfDiameter = 0.01f;
constexpr float kDefaultAlpha = 2.f / 3.f;
// Half the photons aimed at the delta surfaces (when there are any): a small glass object
// then gets a good share of them, the rest of the scene keeps half.
constexpr float kDefaultAim = 0.5f;
// The most photons one iteration's product holds (27 bytes each, stored in Redis): the
// passes stop doubling at the power of two of batches below it (IterationShareCap).
constexpr uint64_t kMaxPhotonsPerIteration = 10'000'000;
constexpr uint64_t kPhotonStreamBase = uint64_t(1) << 40;
constexpr char kMagic[] = "TSP2";

class SPPMIntegrator final : public Integrator {
public:
    SPPMIntegrator(int max_depth, uint32_t photons, float radius, float alpha, float aim, uint32_t time_slices,
                   const std::string& product)
        : max_depth_(max_depth), photons_(photons), radius_(radius), alpha_(alpha), aim_(aim),
          time_slices_(time_slices) {
        if (!product.empty()) {
            size_t offset = 0;
            PhotonProductParse(product, kMagic, 1, &offset, "sppm");
            map_.Parse(product, &offset, "sppm");
            if (offset != product.size()) throw std::invalid_argument("sppm: the scene product has trailing bytes");
        }
    }

    static const IntegratorInfo& Info() {
        static const IntegratorInfo info{
            .name = "sppm",
            .description = "progressive photon mapping (Knaus-Zwicker radius schedule): consistent, "
                           "a photon pass per iteration",
            .scene_passes = true,
            .stop_per_tile = false,
            .delta_caustics = true,
            .traces_light_paths = true,
            .params = {{"photons", "photon paths per batch (default 100000)"},
                       {"radius", "first batch's disk-kernel radius in scene units (default: a hundredth of "
                                  "the scene's bounding diameter)"},
                       {"alpha", "radius reduction, 0 < alpha < 1: r_j = r_1 j^((alpha-1)/2) (default 2/3)"},
                       {"aim", "share of photons aimed at the smooth mirrors and glass (a projection map), "
                               "0 to 1 (default 0.5; no effect without such surfaces or with motion)"},
                       {"time_slices", "with motion blur, the first batch's slices of the shutter; a visible "
                                       "point merges with photons of its own slice (default 32)"}},
            .iteration_cap = {"photons", kDefaultPhotons, "", double(kMaxPhotonsPerIteration)},
            .pilot_candidate = IntegratorInfo::PilotCandidate::kMirrorsOrGlassWithNoiseTarget,
            .merging_alpha = kDefaultAlpha,
        };
        return info;
    }
    const IntegratorInfo& info() const override { return Info(); }

    float BatchRadius(uint64_t batch) const { return radius_ * std::pow(double(batch), (alpha_ - 1.0) / 2.0); }

    std::string RunScenePass(const Scene& scene, uint32_t seed, uint32_t iteration, int threads) const override {
        const auto [first, count] = IterationBatches(iteration, IterationShareCap(photons_, kMaxPhotonsPerIteration));
        std::vector<StoredPhoton> photons;
        PhotonFilter filter;
        filter.min_bounces = 1;  // direct light is next event estimation's
        const ShutterSlices slices =
            PassShutterSlices(scene, time_slices_, std::pow(double(first), 0.5 * (1.0 - alpha_)), photons_);
        for (uint64_t j = first; j < first + count; ++j) {
            std::vector<StoredPhoton> batch =
                TracePhotons(scene, seed, kPhotonStreamBase + j, photons_, max_depth_, filter, slices, threads, aim_);
            const float r = float(BatchRadius(j));
            for (StoredPhoton& ph : batch) {
                ph.power = ph.power / float(count);  // the iteration averages its batches
                ph.radius = r;
            }
            photons.insert(photons.end(), batch.begin(), batch.end());
        }
        std::string bytes = PhotonProductBegin(kMagic, iteration, 1);
        PhotonGrid::Serialize(photons, float(BatchRadius(first)), slices, &bytes);
        return bytes;
    }

    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler& sampler, SplatFilm&,
                      IntegratorCounters*) const override {
        const bool lights = !scene.light_sampler().empty();
        return TraceVisiblePoints(scene, cs, sampler, max_depth_,
                                  [&](const SurfaceHit& hit, const BSDF& bsdf, const Frame& frame, Vec3 wo, Color) {
                                      Color L = EstimateRadiance(map_, hit, bsdf, frame, wo, PhotonKernel::kDisk);
                                      if (lights) L += SampleDirectLight(scene, hit, bsdf, frame, wo, sampler, false);
                                      return L;
                                  });
    }

private:
    int max_depth_;
    uint32_t photons_;
    float radius_, alpha_, aim_;
    uint32_t time_slices_;  // K_1
    PhotonGrid map_;
};

}  // namespace

IntegratorEntry SPPMIntegratorEntry() {
    return {SPPMIntegrator::Info, [](const IntegratorSettings& s, const Scene& scene) -> std::unique_ptr<Integrator> {
                const float photons = s.Param("photons", kDefaultPhotons);
                if (!(photons >= 1.f && photons <= float(kMaxPhotonsPerIteration) && photons == std::floor(photons)))
                    throw std::invalid_argument("sppm photons must be a whole number from 1 to 1e7 (photon paths per batch)");
                const float radius = s.Param("radius", kDefaultRadiusOfDiameter * 2.f * scene.scene_radius());
                if (!(radius > 0.f && std::isfinite(radius)))
                    throw std::invalid_argument("sppm radius must be a finite number > 0");
                const float alpha = s.Param("alpha", kDefaultAlpha);
                if (!(alpha > 0.f && alpha < 1.f)) throw std::invalid_argument("sppm alpha must be between 0 and 1 (exclusive)");
                const float aim = s.Param("aim", kDefaultAim);
                if (!(aim >= 0.f && aim <= 1.f)) throw std::invalid_argument("sppm aim must be between 0 and 1");
                if (aim == 1.f)  // photons would reach only what the delta surfaces send
                    throw std::invalid_argument("sppm aim must be below 1: the photons would skip every path that "
                                                "does not start at a mirror or glass");
                return std::make_unique<SPPMIntegrator>(s.max_depth, uint32_t(photons), radius, alpha, aim,
                                                        TimeSlicesSetting(s, "sppm"), s.scene_product);
            }};
}

}  // namespace tessera
