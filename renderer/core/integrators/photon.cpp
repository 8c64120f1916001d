// Jensen's two-pass photon mapping (Jensen 2001; docs/integrators.md, "photon").
//
// Scene pass: a global map (every landing of `photons` photon paths on a non-specular
// surface) and a caustic map (the landings of `caustic_photons` more paths after one or
// more specular scatterings only: L S+ D; all of them aimed at the delta surfaces, which
// every such path crosses: photon_map.h). Tile pass: the camera ray follows delta lobes
// to the visible points (visible_point.h); at each the outgoing radiance is split by the
// last scattering of the light arriving there:
//   - from a light directly (L D E): next event estimation;
//   - through specular surfaces only (L S+ D E): the caustic map, radius `caustic_radius`;
//   - from another non-specular surface, maybe through specular ones (L .* D S* D E): a
//     final gather of `gather` BSDF-sampled rays, each followed through delta lobes to a
//     non-specular surface where the global map (radius `radius`) gives the radiance.
// The three are disjoint and cover every path, so only the kernels bias the image (both
// Epanechnikov: K(d) = 2 (1 - d^2/r^2) / (pi r^2)). Each iteration traces fresh photons,
// so averaging iterations lowers the noise but not the kernel bias.
//
// Motion blur (docs/motion.md): both maps' photon paths live in `time_slices` slices of
// the shutter (shutter_slices.h), and a visible point or gather point sees only the
// photons of its camera sample's slice: a time kernel 1/K wide, fixed like the radii.
#include <cmath>
#include <stdexcept>

#include "direct_light.h"
#include "integrator.h"
#include "photon_map.h"
#include "visible_point.h"

namespace tessera {

namespace {

constexpr float kDefaultPhotons = 200000.f;
// Every caustic path is aimed at the delta surfaces, so a quarter million of them land as
// many caustic photons as over ten million unaimed ones would on a small glass object
// (examples/caustic: ~9e4 caustic photons, 6.8 MB with the global map, in 0.2 s).
constexpr float kDefaultCausticPhotons = 250000.f;
constexpr float kDefaultRadiusOfDiameter = 0.02f;
constexpr float kDefaultCausticRadiusOfDiameter = 0.005f;
constexpr float kDefaultGather = 8.f;
constexpr float kMaxPhotons = 1e7f;
// Delta lobes a gather ray follows before it gives up on finding a non-specular surface.
constexpr int kGatherSpecularDepth = 16;
constexpr uint64_t kPhotonStreamBase = uint64_t(1) << 40;
constexpr char kMagic[] = "TPJ2";

class PhotonIntegrator final : public Integrator {
public:
    PhotonIntegrator(int max_depth, uint32_t photons, uint32_t caustic_photons, float radius, float caustic_radius,
                     int gather, uint32_t time_slices, const std::string& product)
        : max_depth_(max_depth), photons_(photons), caustic_photons_(caustic_photons), radius_(radius),
          caustic_radius_(caustic_radius), gather_(gather), time_slices_(time_slices) {
        if (!product.empty()) {
            size_t offset = 0;
            PhotonProductParse(product, kMagic, 2, &offset, "photon");
            global_.Parse(product, &offset, "photon");
            caustic_.Parse(product, &offset, "photon");
            if (offset != product.size()) throw std::invalid_argument("photon: the scene product has trailing bytes");
        }
    }

    static const IntegratorInfo& Info() {
        static const IntegratorInfo info{
            .name = "photon",
            .description = "photon mapping (Jensen): global and caustic maps, final gather, direct light by NEE; "
                           "biased",
            .scene_passes = true,
            .stop_per_tile = false,
            .delta_caustics = true,
            .traces_light_paths = true,
            .params = {{"photons", "photon paths for the global map per iteration (default 200000)"},
                       {"caustic_photons", "photon paths for the caustic map per iteration (default 250000)"},
                       {"radius", "global map's kernel radius in scene units (default: 2 % of the scene's "
                                  "bounding diameter)"},
                       {"caustic_radius", "caustic map's kernel radius (default: 0.5 % of the diameter)"},
                       {"gather", "final-gather rays per visible point (default 8)"},
                       {"time_slices", "with motion blur, the slices of the shutter; a point merges with "
                                       "photons of its own slice (default 32)"}},
        };
        return info;
    }
    const IntegratorInfo& info() const override { return Info(); }

    std::string RunScenePass(const Scene& scene, uint32_t seed, uint32_t iteration, int threads) const override {
        const uint64_t stream = kPhotonStreamBase + 2 * uint64_t(iteration);
        const ShutterSlices global_slices = PassShutterSlices(scene, time_slices_, 1.0, photons_);
        const ShutterSlices caustic_slices = PassShutterSlices(scene, time_slices_, 1.0, caustic_photons_);
        std::vector<StoredPhoton> global =
            TracePhotons(scene, seed, stream, photons_, max_depth_, PhotonFilter{}, global_slices, threads);
        std::vector<StoredPhoton> caustic =
            TracePhotons(scene, seed, stream + 1, caustic_photons_, max_depth_,
                         PhotonFilter{.min_bounces = 1, .caustic_only = true}, caustic_slices, threads,
                         /*specular_aim=*/1.f);
        for (StoredPhoton& ph : global) ph.radius = radius_;
        for (StoredPhoton& ph : caustic) ph.radius = caustic_radius_;
        std::string bytes = PhotonProductBegin(kMagic, iteration, 2);
        PhotonGrid::Serialize(global, radius_, global_slices, &bytes);
        PhotonGrid::Serialize(caustic, caustic_radius_, caustic_slices, &bytes);
        return bytes;
    }

    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler& sampler, SplatFilm&,
                      IntegratorCounters*) const override {
        const bool lights = !scene.light_sampler().empty();
        return TraceVisiblePoints(
            scene, cs, sampler, max_depth_, [&](const SurfaceHit& hit, const BSDF& bsdf, const Frame& frame, Vec3 wo, Color) {
                Color L = EstimateRadiance(caustic_, hit, bsdf, frame, wo, PhotonKernel::kEpanechnikov);
                if (lights) L += SampleDirectLight(scene, hit, bsdf, frame, wo, sampler, false);
                return L + FinalGather(scene, hit, bsdf, frame, wo, sampler);
            });
    }

private:
    // Light reaching the visible point from other non-specular surfaces: the global map's
    // radiance where BSDF-sampled rays, followed through delta lobes, land.
    Color FinalGather(const Scene& scene, const SurfaceHit& x, const BSDF& bsdf, const Frame& frame, Vec3 wo,
                      PixelSampler& sampler) const {
        const Vec3 wo_local = frame.ToLocal(wo);
        Color sum(0.f);
        for (int g = 0; g < gather_; ++g) {
            const float uc = sampler.Get1D();
            const std::optional<BSDFSample> bs = bsdf.Sample_f(wo_local, uc, sampler.Get2D());
            // A delta sample is the camera walk's to follow; here it adds nothing.
            if (!bs || bs->is_specular || !(bs->pdf > 0.f) || IsBlack(bs->f)) continue;
            Vec3 wi = Normalize(frame.FromLocal(bs->wi));
            if (!SidesAgree(wo, wi, x.ng, wo_local, bs->wi)) continue;
            Color beta = bs->f * (std::abs(bs->wi.z) / bs->pdf);
            Ray ray{OffsetRayOrigin(x.p, x.p_error, x.ng, wi), wi};
            for (int depth = 0; depth < kGatherSpecularDepth; ++depth) {
                SurfaceHit y;
                if (!scene.Intersect(ray, &y)) break;
                const BSDF by = scene.BSDFAt(y, TransportMode::Radiance);
                if (by.Flags() == kBSDFUnset) break;
                const Frame fy = Frame::FromZ(y.ns);
                const Vec3 wy = -ray.d;
                if (by.IsNonSpecular()) {
                    sum += beta * EstimateRadiance(global_, y, by, fy, wy, PhotonKernel::kEpanechnikov);
                    break;
                }
                const Vec3 wy_local = fy.ToLocal(wy);
                const float uy = sampler.Get1D();
                const std::optional<BSDFSample> sy = by.Sample_f(wy_local, uy, sampler.Get2D());
                if (!sy || !(sy->pdf > 0.f) || IsBlack(sy->f)) break;
                const Vec3 wn = Normalize(fy.FromLocal(sy->wi));
                if (!SidesAgree(wy, wn, y.ng, wy_local, sy->wi)) break;
                beta *= sy->f * (std::abs(sy->wi.z) / sy->pdf);
                ray = {OffsetRayOrigin(y.p, y.p_error, y.ng, wn), wn};
            }
        }
        return sum / float(gather_);
    }

    int max_depth_;
    uint32_t photons_, caustic_photons_;
    float radius_, caustic_radius_;
    int gather_;
    uint32_t time_slices_;
    PhotonGrid global_, caustic_;
};

}  // namespace

IntegratorEntry PhotonIntegratorEntry() {
    return {PhotonIntegrator::Info, [](const IntegratorSettings& s, const Scene& scene) -> std::unique_ptr<Integrator> {
                const float diameter = 2.f * scene.scene_radius();
                auto count = [&](const char* name, float fallback) {
                    const float n = s.Param(name, fallback);
                    if (!(n >= 0.f && n <= kMaxPhotons && n == std::floor(n)))
                        throw std::invalid_argument(std::string("photon ") + name +
                                                    " must be a whole number from 0 to 1e7");
                    return uint32_t(n);
                };
                auto length = [&](const char* name, float fallback) {
                    const float r = s.Param(name, fallback);
                    if (!(r > 0.f && std::isfinite(r)))
                        throw std::invalid_argument(std::string("photon ") + name + " must be a finite number > 0");
                    return r;
                };
                const uint32_t photons = count("photons", kDefaultPhotons);
                const uint32_t caustic = count("caustic_photons", kDefaultCausticPhotons);
                const float radius = length("radius", kDefaultRadiusOfDiameter * diameter);
                const float caustic_radius = length("caustic_radius", kDefaultCausticRadiusOfDiameter * diameter);
                const float gather = s.Param("gather", kDefaultGather);
                if (!(gather >= 1.f && gather <= 1024.f && gather == std::floor(gather)))
                    throw std::invalid_argument("photon gather must be a whole number from 1 to 1024");
                return std::make_unique<PhotonIntegrator>(s.max_depth, photons, caustic, radius, caustic_radius,
                                                          int(gather), TimeSlicesSetting(s, "photon"), s.scene_product);
            }};
}

}  // namespace tessera
