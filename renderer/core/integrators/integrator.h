// The one interface every light-transport method implements, and the registry that names
// them (after pbrt-v4's Integrator::Create and Mitsuba 3's plugin table).
//
// The renderer loops over pixel samples (render.cpp); an integrator turns one camera
// sample into an estimate for its pixel and, if it splats, into contributions anywhere on
// the frame. Everything a caller outside the core needs to know about an integrator
// (whether its image needs the splat normalisation, whether tiles may stop on their own)
// is in its IntegratorInfo, so no caller lists integrators by name.
#pragma once

#include <algorithm>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "camera.h"
#include "sampler.h"
#include "scene.h"
#include "splat_film.h"

namespace tessera {

struct PathSample {
    Color radiance;
    float alpha = 0.f;  // 1 where the camera ray hit geometry
};

// A setting an integrator accepts besides the common ones (IntegratorSettings).
struct IntegratorParam {
    std::string_view name;
    std::string_view description;
};

// The classes of light paths (Heckbert's notation) an integrator may declare itself blind
// to, for the integrator matrix (tests/renderer/test_integrator_matrix.py): each analytic
// scene there names the classes its closed form needs, and an integrator is checked on
// every scene whose classes it sees. L: a light with area (emissive triangles, sphere
// lights); Ld: a delta light (distant, point); Lenv: the dome; D: a diffuse (non-delta)
// scattering; S: a delta (smooth mirror or glass) scattering; E: the pinhole camera.
inline constexpr std::string_view kPathClasses[] = {"L E", "L D E", "Ld D E", "Lenv D E", "L D D+ E", "L S+ E"};

// A class of kPathClasses an integrator does not estimate, and why (one sentence, shown in
// the matrix and in docs/integrators.md).
struct PathExclusion {
    std::string_view paths;
    std::string_view reason;
};

struct IntegratorInfo {
    std::string_view name;
    std::string_view description;  // one line, for `tessera render --integrator help`
    // Writes across tiles: light paths land anywhere on the frame (SplatFilm), and the image
    // is the tiles' own pixels plus the summed splats normalised by the light paths traced.
    bool splats = false;
    // Needs scene-wide work before each iteration's tile passes (Integrator::RunScenePass):
    // the farm runs it once per iteration as a task of its own and hands its product to
    // every tile of that iteration (IntegratorSettings::scene_product).
    bool scene_passes = false;
    // A tile may stop on a noise target on its own; otherwise the whole image advances in
    // lockstep (splats land on other tiles, so a tile's noise is not its own to judge).
    bool stop_per_tile = true;
    // Estimates every light path (the full transport, unbiased): `auto` chooses among these.
    bool complete = false;
    // Finds caustics of delta lights through delta or near-delta lobes (L S+ D E from a
    // point): path tracing cannot, so `auto` needs such an integrator for those scenes.
    bool delta_caustics = false;
    // Shades what it sees of curves (Embree round curves). Radiosity reads every surface
    // from its element mesh, which has no curves: they show black there.
    bool shades_curves = true;
    // Renders participating media (docs/media.md). One that does not refuses a scene with
    // media when created (Integrator::Create) rather than render it as if they were absent.
    bool handles_media = false;
    // Of those, renders grid media too (heterogeneous volumes, media/grid_medium.h); one
    // that handles only homogeneous media refuses a scene with a grid medium.
    bool handles_grid_media = false;
    // Honours UsdLux light and shadow links (light_links.h) in every light path it
    // estimates. One that does not is named in one warning for a scene with links
    // (tessera_base.integrators.scene_warnings); its image ignores them where it cannot.
    bool honours_light_links = false;
    // Starts paths at the lights (Scene::SampleEmission): one that does refuses a scene with a
    // light kind that cannot start them (Scene::kind_without_light_paths: portals).
    bool traces_light_paths = false;
    std::vector<IntegratorParam> params = {};
    // What a pixel estimates: "radiance", or another quantity (ao: "ambient occlusion"),
    // which the integrator matrix checks on its own closed forms.
    std::string_view estimates = "radiance";
    // The light paths it does not estimate (kPathClasses), each with its reason; empty:
    // every class. An integrator is checked on every matrix scene it sees: a new one enters
    // the matrix by being registered, and leaves a scene only by declaring why here.
    std::vector<PathExclusion> blind_to = {};
    // For a progressive scene-pass integrator whose iterations trace batches (sppm, vcm):
    // setting `param` (default `per_batch`) counts a batch's paths, and an iteration holds
    // at most `max_per_iteration` of them (setting `max_param` if named). The passes'
    // schedule reads it (IterationShareCap; tessera.protocol.pass_range): empty `param`, no cap.
    struct IterationCap {
        std::string_view param;
        double per_batch = 0;
        std::string_view max_param;
        double max_per_iteration = 0;
    } iteration_cap = {};
    // Which renders `auto`'s measuring pilot (tessera/tessera/pilot.py) tries it in: never;
    // always; or only for a scene with mirrors or glass (Scene::has_delta_surfaces) rendered to
    // a noise target (merging converges over iterations; a fixed-spp render is one). A scene
    // with delta-light caustics also leaves out a candidate without `delta_caustics`.
    enum class PilotCandidate { kNever, kAlways, kMirrorsOrGlassWithNoiseTarget };
    PilotCandidate pilot_candidate = PilotCandidate::kNever;
    // A merging integrator's default radius exponent (its `alpha` setting's default): its
    // variance falls as J^-alpha over J iterations, which the pilot's efficiency handicaps.
    // 0: not a merging integrator.
    double merging_alpha = 0;
    // Its scene-wide product is the whole image's solution, independent of the camera (one
    // primary ray a pixel reads it): `tessera preview` solves it once and re-renders any view.
    bool view_independent_product = false;
};

// Settings common to every integrator, plus the named extras its info declares.
struct IntegratorSettings {
    int max_depth = 64;
    std::map<std::string, float> params;
    // For an integrator with scene_passes: the product of the current iteration's scene
    // pass (RunScenePass), opaque bytes to everything but that integrator; empty otherwise.
    std::string scene_product;
    // The value of an extra setting, or `fallback` if it was not given.
    float Param(const std::string& name, float fallback) const {
        auto it = params.find(name);
        return it == params.end() ? fallback : it->second;
    }
};

// One pixel sample as the renderer hands it over: the camera ray, its clipping range, and
// the identity of the sample, from which further sampler streams are opened (stream 0 is
// the camera's and is passed separately; light subpaths use stream 1; the AOVs stream 2).
struct CameraSample {
    Ray ray;
    float t_min = 0.f, t_max = std::numeric_limits<float>::infinity();
    uint32_t seed = 0;
    uint64_t pixel_index = 0;
    uint32_t sample_index = 0;
    SamplerKind sampler_kind = SamplerKind::kOwenSobol;
    // False for a pixel outside the render's camera window (a crop): its own estimate is
    // discarded, only its light paths' splats are wanted. A splatting integrator may then
    // skip its camera-side work, but the splats it makes must be those of a full render,
    // bit for bit (the same sampler values).
    bool camera_work = true;
    PixelSampler Stream(uint32_t stream) const {
        return PixelSampler(seed, pixel_index, sample_index, stream, sampler_kind);
    }
};

// The instant of the shutter at which a scene pass's light path or photon path lives: the
// first dimension of its own stream, drawn only when something moves (still scenes keep
// their streams and products bit for bit). Held for the whole path with ShutterTimeScope,
// as RenderTile holds a camera sample's instant for its camera path.
inline float LightPathInstant(const Scene& scene, PixelSampler& sampler) {
    return scene.has_motion() ? sampler.Get1D() : 0.5f;
}

// One pixel sample handed to an integrator that estimates many at once (SampleBatch): its
// camera ray and clipping range, and its stream 0 past the camera's dimensions.
struct BatchSample {
    Ray ray;
    float t_min, t_max;
    PixelSampler sampler;
};

// Per-thread counters an integrator may add to.
struct IntegratorCounters {
    uint64_t rejected_splats = 0;  // splats that were not finite and >= 0: a bug if > 0
};

class Integrator {
public:
    virtual ~Integrator() = default;
    virtual const IntegratorInfo& info() const = 0;
    // One pixel sample: the estimate for its own pixel. `sampler` is stream 0, past the
    // camera's dimensions. A splatting integrator also adds to `film` (full frame).
    virtual PathSample Sample(const Scene& scene, const Camera& camera, const CameraSample& cs,
                              PixelSampler& sampler, SplatFilm& film, IntegratorCounters* counters) const = 0;

    // Whether it estimates batches of pixel samples (SampleBatch) for this render: chosen
    // when it was built for the scene, so the renderer asks once per tile, not per sample.
    virtual bool samples_in_batches() const { return false; }
    // For samples_in_batches(): the estimate of each of n pixel samples of a still shutter
    // (no motion, no moving camera), each the bits Sample would return for it alone.
    virtual void SampleBatch(const Scene&, BatchSample*, PathSample*, size_t) const {}

    // For an integrator with scene_passes: the scene-wide work of iteration `iteration`
    // (e.g. tracing a batch of photons), run once before that iteration's tile passes, and
    // its product. It must be a pure function of (scene, settings, seed, iteration), so
    // that any machine computes the same bytes; `threads` only decides who computes it.
    // The integrator it is called on may have been built with an empty scene_product.
    virtual std::string RunScenePass(const Scene& scene, uint32_t seed, uint32_t iteration, int threads) const;

    // The registered integrator of that name, built for one render; throws
    // std::invalid_argument for an unknown name or a setting it does not take.
    static std::unique_ptr<Integrator> Create(std::string_view name, const IntegratorSettings& settings,
                                              const Scene& scene);
};

// Every registered integrator, in registry order (integrators/registry.cpp).
const std::vector<IntegratorInfo>& RegisteredIntegrators();
// nullptr if no integrator has that name.
const IntegratorInfo* FindIntegrator(std::string_view name);
// The `auto` rule: the first complete integrator in registry order, among those that find
// delta-light caustics if the scene has them.
std::string_view AutoIntegrator(bool scene_has_delta_caustics);

// The most batches an iteration may hold, C: the largest power of two with C * per_batch
// <= max_per_iteration (at least 1). The passes double up to C times the first pass's
// samples and then stay there (tessera.protocol.pass_range computes the same C from
// IntegratorInfo::iteration_cap), so that every iteration holds exactly its share of
// batches. Capping the batches while the passes kept doubling would have late passes'
// samples all merge with one capped set of paths, whose noise no number of samples
// averages away: measured, vcm's relMSE stopped at 2.5e-3 from 1024 to 2048 spp on
// examples/caustic at 64 x 64.
inline uint64_t IterationShareCap(double per_batch, double max_per_iteration) {
    uint64_t cap = 1;
    while (per_batch > 0 && double(cap) * 2 * per_batch <= max_per_iteration && cap < (uint64_t(1) << 40)) cap *= 2;
    return cap;
}

// The batches (of photons, of light paths) iteration `iteration` of a progressive
// scene-pass integrator traces when the film weighs an iteration by its samples and the
// passes double up to `cap` (a power of two, IterationShareCap) times the first pass's
// samples (tessera.protocol.pass_range: 1, 1, 2, 4, ..., cap, cap, ...): batches [first,
// first + count), counted from 1, count the iteration's share of samples. Each batch then
// weighs the same in the image, and a radius schedule over batches (sppm, vcm) stays
// Knaus-Zwicker's.
struct BatchRange {
    uint64_t first = 1, count = 1;
};
inline BatchRange IterationBatches(uint32_t iteration, uint64_t cap) {
    if (iteration == 0) return {1, 1};
    cap = std::max<uint64_t>(cap, 1);
    // Iteration k >= 1 shares 2^(k-1) while that is below the cap; the shares before it
    // sum to 2^(k-1). From k_c (2^(k_c - 1) = cap) on, every iteration shares cap.
    uint32_t k_c = 1;
    while ((uint64_t(1) << (k_c - 1)) < cap) ++k_c;
    if (iteration <= k_c) {
        const uint64_t share = uint64_t(1) << (iteration - 1);
        return {share + 1, share};
    }
    return {cap * (uint64_t(iteration) - k_c + 1) + 1, cap};
}

// What an integrator's file hands the registry.
struct IntegratorEntry {
    const IntegratorInfo& (*info)();
    std::unique_ptr<Integrator> (*create)(const IntegratorSettings& settings, const Scene& scene);
};

}  // namespace tessera
