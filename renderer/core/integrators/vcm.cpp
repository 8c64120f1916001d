// Vertex connection and merging (Georgiev et al. 2012; Hachisuka et al. 2012's unified path
// sampling is the same idea): BDPT's connections plus photon-style merging of camera
// vertices with the light vertices of many light paths, all under one power-heuristic MIS.
//
// Per iteration the scene pass traces `light_paths` light subpaths (streams keyed by seed,
// iteration and path index) and keeps every vertex a camera vertex can merge with: a
// non-delta surface vertex past the light's own, with its position, the direction it came
// from, its throughput and the light-side quantities its MIS weight needs (below), sorted
// into a PointHashGrid of cells one merging radius wide. The grid is the product.
//
// A pixel sample is first exactly a bdpt sample: its own light subpath (stream 1), every
// (s, t) connection, the t = 1 strategies splatted. Its MIS weights also count merging
// (bdpt_internal's MISWeight with merge_eta). Then every non-delta surface vertex of its
// camera subpath merges with the product's light vertices within the radius r:
//     L += beta_cam * f(wo, wi_light) * beta_light * w_VM / (N pi r^2)
// with N the light paths of the iteration. Which light vertices a camera vertex sees is
// a function of the product and the vertex only, so the image does not depend on tiling.
//
// MIS (in pbrt's ratio form, as in bdpt_internal.h): strategies of one path y_0 (light) ..
// y_k (camera) are the connections VC_b (y_0..y_{b-1} from the light, the rest from the
// camera) and the mergings VM_j at interior non-delta surfaces, with
//     p(VM_j) = p(VC_j) * p_L(y_j) * eta,   eta = N pi r^2,
// p_L(y_j) the light side's area density of y_j. A merge's weight sums the ratios of all
// strategies to VC_j: the camera side's from the camera subpath, the light side's
// R_{j-1}^2 Q_{j-1}, where the scene pass folds everything below y_{j-1} into
//     Q_m = [VC_m] + [VM_m] (p_L(y_m) eta)^2 + R_{m-1}^2 Q_{m-1},   Q_0 = [VC_0],
//     R_m = p_E(y_m) / p_L(y_m),
// and only p_E(y_{j-1}) (the camera vertex's BSDF sampling toward y_{j-1}) is left to the
// merge. Densities past a delta lobe are 0 and remapped to 1, as bdpt does: any rule the
// strategies share keeps the weights a partition of unity.
//
// Direct light is not merged (the default; `direct_merging` = 1 merges it too, as Georgiev
// et al. do): the strategies are the connections and the mergings VM_j with j >= 2 only,
// and both the merge estimator and every MIS weight leave VM_1 out, so the weights still
// sum to one. Merging estimates the irradiance blurred over the disk of radius r, and at
// y_1 MIS hands it nearly all the weight (p_L(y_1) eta, the light vertices expected in the
// disk, is in the hundreds on a lit surface), so the blur of direct light showed as a bias
// of O((r / distance to the light)^2): -3.4 % on a floor 1.5 below a 2 x 1 rect light at
// r = 0.42, -13 ... +28 % (dark where the irradiance is concave, bright in its convex tail)
// on large planes whose default radius (0.005 of the scene's diameter) is large. Every
// y_1 (a non-delta surface lit by the light's own vertex) is reached as well by next event
// estimation (VC_1), which has no kernel; sppm does the same (direct light by NEE only).
//
// Radius schedule (Georgiev et al. 2012, from Knaus & Zwicker 2011): batch j (from 1) of
// `light_paths` light paths merges within r_j = r_1 j^((alpha - 1) / 2), so the kernel's
// bias and the merging variance both vanish as batches grow (consistent, 0 < alpha < 1).
// The film weighs an iteration by its samples and the farm's passes double (1, 1, 2, 4,
// ... times the first: tessera.protocol.pass_range), so iteration k traces as many batches
// as its share of samples (1 for k = 0, 2^(k-1) after; `grow` = 1, the default), all with
// the radius of its first batch and N their paths: otherwise the camera samples of a late
// pass would all merge with one batch's light vertices, whose noise no number of samples
// averages away (relMSE stopped falling at ~0.03 on examples/caustic at 64 x 64). An
// iteration holds at most 4e6 light paths (a product of ~140 MB there): the passes stop
// doubling at the power of two of batches below that (IterationShareCap: 32 at the
// default 1e5 a batch), so every iteration keeps its share. `grow` = 0 keeps
// one batch an iteration (r_k = r_1 (k + 1)^((alpha - 1) / 2)), for iterations of equal
// samples.
//
// Motion blur (docs/motion.md): a camera sample and its own light subpath live at the
// sample's instant; the scene pass's light paths in K_i time slices of the shutter
// (shutter_slices.h), K_i = ceil(K_1 i^((1 - alpha) / 2)). A camera vertex merges only
// with its own slice's light vertices (the grid keys cells by slice), and N above is the
// slice's path count n_b (in the merge's 1 / (n_b pi r^2) and in every MIS weight of the
// sample).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "bdpt_internal.h"
#include "integrator.h"
#include "point_hash_grid.h"
#include "shutter_slices.h"

namespace tessera {

namespace {

using namespace bdpt_internal;

constexpr float kDefaultRadiusOfDiameter = 0.005f;
constexpr float kDefaultLightPaths = 100000.f;
constexpr float kDefaultAlpha = 0.75f;
// Light-path streams are keyed by the iteration in a pixel-index range no image reaches
// and apart from photon_direct's (2^40 + iteration), so they are independent of every
// camera sample's streams and of other integrators' photons.
constexpr uint64_t kLightPathStreamBase = (uint64_t(1) << 40) + (uint64_t(1) << 36);
constexpr uint32_t kLightPathStream = 4;
constexpr uint64_t kMaxLightPathsPerIteration = 4'000'000;
// Light paths per work item: each item fills its own list, joined in item order.
constexpr uint32_t kPathsPerChunk = 1024;

// A stored light vertex y_j (j >= 1).
struct LightVertex {
    float p[3];
    float wo[3];          // unit, toward y_{j-1}
    float beta[3];        // light subpath throughput up to y_j
    float pdf_fwd;        // p_L(y_j), area (0 past a delta lobe)
    float prev_pdf_fwd;   // p_L(y_{j-1})
    float prev_convert;   // solid angle at y_j toward y_{j-1} -> y_{j-1}'s measure
    float prev_sum;       // Q_{j-1}
    uint16_t index;       // j
    uint8_t prev_delta;   // y_{j-1} scattered by a delta lobe: VC_j does not exist
    uint8_t time_slice;   // b: the slice of the shutter its path lives in (0 in a still scene)
};
static_assert(sizeof(LightVertex) == 56);

constexpr char kMagic[4] = {'T', 'V', 'C', '5'};
struct Header {
    char magic[4];
    uint32_t iteration;
    uint32_t light_paths;  // the setting (per batch)
    uint32_t merging;
    float radius;          // r of this iteration
    uint32_t time_slices;  // K_i: 1 in a still scene
    uint32_t paths;        // N: light paths traced in this iteration
    uint32_t grow;
    uint32_t first_merge;  // the smallest light-vertex index j merged: 2, or 1 with direct_merging
};

class VCMIntegrator final : public Integrator {
public:
    VCMIntegrator(int max_depth, uint32_t light_paths, uint32_t max_iteration_paths, float radius, float alpha,
                  bool merging, bool grow, bool direct_merging, uint32_t time_slices, const std::string& product)
        : max_depth_(max_depth),
          light_paths_(light_paths),
          max_iteration_paths_(max_iteration_paths),
          radius_(radius),
          alpha_(alpha),
          merging_(merging),
          grow_(grow),
          first_merge_(direct_merging ? 1 : 2),
          time_slices_(time_slices) {
        if (!product.empty()) Load(product);
    }

    static const IntegratorInfo& Info() {
        static const IntegratorInfo info{
            .name = "vcm",
            .description = "vertex connection and merging: bdpt plus merging with a scene pass's light "
                           "vertices under one MIS; shrinking radius (consistent); t = 1 splats",
            .splats = true,
            .scene_passes = true,
            .stop_per_tile = false,
            // Consistent, not unbiased: `auto` does not choose it (yet).
            .complete = false,
            .delta_caustics = true,
            .traces_light_paths = true,
            .params = {{"light_paths", "light subpaths in a batch; iteration k traces its pass's share of batches (default 100000)"},
                       {"radius", "merging radius of the first iteration in scene units (default: 0.005 of the "
                                  "scene's bounding diameter)"},
                       {"alpha", "radius schedule r_i = r_1 i^((alpha-1)/2), 0 < alpha < 1 (default 0.75)"},
                       {"merging", "1 to merge, 0 for connections only: then exactly bdpt (default 1)"},
                       {"direct_merging", "1 to merge direct light too (Georgiev et al.'s full VCM: direct light "
                                          "then carries the kernel's blur, a bias of O((r / distance to the "
                                          "light)^2)); 0: direct light by connections only (default 0)"},
                       {"grow", "1: iteration k traces light_paths times its pass's share of samples (1, 1, 2, "
                                "4, ...), as the passes double (default); 0: light_paths every iteration"},
                       {"max_iteration_paths", "the most light paths an iteration traces (its product keeps 56 "
                                               "bytes a merging vertex); the passes stop doubling at the power "
                                               "of two of batches within it (default 4e6, at most 4e6)"},
                       {"time_slices", "with motion blur, the first iteration's slices of the shutter; a camera "
                                       "vertex merges with light paths of its own slice (default 32)"}},
            .iteration_cap = {"light_paths", kDefaultLightPaths, "max_iteration_paths",
                              double(kMaxLightPathsPerIteration)},
            .pilot_candidate = IntegratorInfo::PilotCandidate::kMirrorsOrGlassWithNoiseTarget,
            .merging_alpha = kDefaultAlpha,
        };
        return info;
    }
    const IntegratorInfo& info() const override { return Info(); }

    // The iteration's batches of light paths: the doubling passes' share, or one (grow = 0).
    BatchRange Batches(uint32_t iteration) const {
        return grow_ ? IterationBatches(iteration, IterationShareCap(light_paths_, max_iteration_paths_))
                     : BatchRange{uint64_t(iteration) + 1, 1};
    }
    uint64_t FirstBatch(uint32_t iteration) const { return Batches(iteration).first; }
    uint32_t IterationPaths(uint32_t iteration) const { return uint32_t(Batches(iteration).count * light_paths_); }
    float IterationRadius(uint32_t iteration) const {
        return radius_ * float(std::pow(double(FirstBatch(iteration)), 0.5 * (alpha_ - 1.0)));
    }

    ShutterSlices IterationTimeSlices(const Scene& scene, uint32_t iteration) const {
        return PassShutterSlices(scene, time_slices_, std::pow(double(FirstBatch(iteration)), 0.5 * (1.0 - alpha_)),
                                 IterationPaths(iteration));
    }

    std::string RunScenePass(const Scene& scene, uint32_t seed, uint32_t iteration, int threads) const override {
        Header h{};
        std::memcpy(h.magic, kMagic, 4);
        h.iteration = iteration;
        h.light_paths = light_paths_;
        h.merging = merging_ ? 1 : 0;
        h.radius = IterationRadius(iteration);
        h.paths = IterationPaths(iteration);
        h.grow = grow_ ? 1 : 0;
        h.first_merge = uint32_t(first_merge_);
        const ShutterSlices slices = IterationTimeSlices(scene, iteration);
        h.time_slices = slices.count;
        std::string bytes(sizeof(Header), '\0');
        std::memcpy(bytes.data(), &h, sizeof(Header));
        if (!merging_) return bytes;  // connections only: nothing to merge with

        const uint32_t paths = h.paths, chunks = (paths + kPathsPerChunk - 1) / kPathsPerChunk;
        std::vector<std::vector<LightVertex>> slots(chunks);
        const Camera no_camera{};  // light subpaths never consult the camera
        auto trace = [&](const tbb::blocked_range<uint32_t>& range) {
            thread_local std::vector<Vertex> path;
            if (path.size() < size_t(max_depth_) + 1) path.resize(size_t(max_depth_) + 1);
            Walker walker(scene, no_camera, max_depth_);
            for (uint32_t i = range.begin() * kPathsPerChunk; i < std::min(paths, range.end() * kPathsPerChunk); ++i) {
                PixelSampler sampler(seed, kLightPathStreamBase + iteration, i, kLightPathStream);
                const uint32_t slice = slices.SliceOfPath(i);
                const ShutterTimeScope instant(slices.Instant(i, LightPathInstant(scene, sampler)));
                const float eta = float(slices.Paths(paths, slice)) * kPi * h.radius * h.radius;
                const int n = walker.LightSubpath(sampler, path.data());
                if (n < 2) continue;
                float q = (!path[0].delta && !path[0].delta_light) ? 1.f : 0.f;  // Q_0
                for (int j = 1; j < n; ++j) {
                    const Vertex& v = path[j];
                    const Vertex& prev = path[j - 1];
                    const bool mergeable = j >= first_merge_ && Mergeable(v);
                    if (mergeable && !IsBlack(v.beta)) {
                        LightVertex lv{};
                        lv.p[0] = v.p.x, lv.p[1] = v.p.y, lv.p[2] = v.p.z;
                        lv.wo[0] = v.wo.x, lv.wo[1] = v.wo.y, lv.wo[2] = v.wo.z;
                        lv.beta[0] = v.beta.x, lv.beta[1] = v.beta.y, lv.beta[2] = v.beta.z;
                        lv.pdf_fwd = v.pdf_fwd;
                        lv.prev_pdf_fwd = prev.pdf_fwd;
                        lv.prev_convert = ConvertDensity(1.f, v, prev);
                        lv.prev_sum = q;
                        lv.index = uint16_t(j);
                        lv.prev_delta = prev.delta ? 1 : 0;
                        lv.time_slice = uint8_t(slice);
                        slots[i / kPathsPerChunk].push_back(lv);
                    }
                    // Q_j, for the vertices further along.
                    const float r = Remap0(prev.pdf_rev) / Remap0(prev.pdf_fwd);
                    float next = r * r * q;
                    if (!v.delta && !prev.delta) next += 1.f;
                    if (mergeable) {
                        const float m = Remap0(v.pdf_fwd) * eta;
                        next += m * m;
                    }
                    q = next;
                }
            }
        };
        // Each chunk of paths fills its own slot and the slots are joined in path order, so
        // the product does not depend on the thread count.
        tbb::task_arena arena(threads > 0 ? threads : tbb::this_task_arena::max_concurrency());
        arena.execute([&] { tbb::parallel_for(tbb::blocked_range<uint32_t>(0, chunks, 1), trace); });
        size_t total = 0;
        for (const auto& s : slots) total += s.size();
        std::vector<LightVertex> all;
        all.reserve(total);
        for (auto& s : slots) all.insert(all.end(), s.begin(), s.end());
        return bytes + PointHashGrid<LightVertex>(all, h.radius).Serialize();
    }

    PathSample Sample(const Scene& scene, const Camera& camera, const CameraSample& cs, PixelSampler& sampler,
                      SplatFilm& film, IntegratorCounters* counters) const override {
        thread_local std::vector<Vertex> camera_path, light_path;
        if (camera_path.size() < size_t(max_depth_) + 2) camera_path.resize(size_t(max_depth_) + 2);
        if (light_path.size() < size_t(max_depth_) + 1) light_path.resize(size_t(max_depth_) + 1);
        PixelSampler light_sampler = cs.Stream(1);
        // The merging density of this sample's time slice (the one slice of a still scene).
        const uint32_t slice = slices_.Current();
        const float eta = slice_eta_.empty() ? 0.f : slice_eta_[slice];

        // Connections, as BDPTIntegrator::SampleStrategies (same streams, same order: with
        // merging off the image is bdpt's bit for bit).
        Walker walker(scene, camera, max_depth_);
        PathSample result;
        // Outside a crop (no camera work) only the t = 1 splats are made: their MIS weights
        // read the light subpath and eta only; the scene pass's light vertices stay whole.
        const int n_camera =
            CameraSubpathFor(walker, camera, cs.ray, sampler, camera_path.data(), cs.camera_work);
        const int n_light = walker.LightSubpath(light_sampler, light_path.data());
        if (n_camera > 1 && camera_path[1].type == VertexType::kSurface) result.alpha = 1.f;
        Color L(0.f);
        Vertex sampled;  // the strategy's own endpoint (s = 1 or t = 1), set by Connect
        for (int t = 1; t <= (cs.camera_work ? n_camera : 1); ++t) {
            for (int s = 0; s <= n_light; ++s) {
                const int depth = t + s - 2;
                if ((s == 1 && t == 1) || depth < 0 || depth > max_depth_) continue;
                float px = 0.f, py = 0.f;
                Color c = walker.Connect(light_path.data(), camera_path.data(), s, t, sampler, &sampled, &px, &py);
                if (IsBlack(c)) continue;
                c *= walker.MISWeight(light_path.data(), camera_path.data(), sampled, s, t, eta, first_merge_);
                if (t == 1) {
                    if (!film.Add(px, py, c) && counters) ++counters->rejected_splats;
                } else {
                    L += c;
                }
            }
        }
        if (eta > 0.f && cs.camera_work)
            for (int t = 2; t <= n_camera; ++t) L += Merge(camera_path.data(), t, slice, eta);
        result.radiance = L;
        return result;
    }

private:
    // Merging at camera[t - 1] with every light vertex of its time slice within the
    // radius; eta = n_slice pi r^2.
    Color Merge(const Vertex* camera, int t, uint32_t slice, float eta) const {
        const Vertex& pt = camera[t - 1];
        if (pt.type != VertexType::kSurface || !pt.bsdf.IsNonSpecular() || IsBlack(pt.beta)) return Color(0.f);
        const Vec3 wo_local = pt.frame.ToLocal(pt.wo);
        Color sum(0.f);
        grid_.ForEachNear(pt.p, slice, [&](const LightVertex& q) {
            if (int(q.index) + t - 2 > max_depth_) return;
            const Vec3 wi(q.wo[0], q.wo[1], q.wo[2]);
            const Vec3 wi_local = pt.frame.ToLocal(wi);
            if (!SidesAgree(pt.wo, wi, pt.ng, wo_local, wi_local)) return;
            const Color f = pt.bsdf.f(wo_local, wi_local);
            if (IsBlack(f)) return;
            sum += f * Color(q.beta[0], q.beta[1], q.beta[2]) * MergeWeight(camera, t, q, wo_local, wi_local, eta);
        });
        return pt.beta * sum * (1.f / eta);
    }

    // The power-heuristic weight of merging camera[t - 1] with light vertex q: the
    // merging's own ratio to VC_j squared over the sum of every strategy's (header).
    float MergeWeight(const Vertex* camera, int t, const LightVertex& q, Vec3 wo_local, Vec3 wi_local,
                      float eta) const {
        const Vertex& pt = camera[t - 1];
        const float vm = Remap0(q.pdf_fwd) * eta;
        float total = vm * vm + (q.prev_delta ? 0.f : 1.f);
        // Camera side: p_L of camera[t - 2] is pt's BSDF sampling it from the light's side.
        const float pl_before = ConvertDensity(pt.bsdf.PDF(wi_local, wo_local), pt, camera[t - 2]);
        auto pl = [&](int i) { return i == t - 1 ? q.pdf_fwd : i == t - 2 ? pl_before : camera[i].pdf_rev; };
        float r = 1.f;
        for (int i = t - 1; i > 0; --i) {
            r *= Remap0(pl(i)) / Remap0(camera[i].pdf_fwd);
            const bool delta_i = i == t - 1 ? false : camera[i].delta;
            if (!delta_i && !camera[i - 1].delta) total += r * r;
            if (i - 1 >= 1 && Mergeable(camera[i - 1])) {
                const float m = r * Remap0(pl(i - 1)) * eta;
                total += m * m;
            }
        }
        // Light side: R_{j-1}^2 Q_{j-1}, with p_E(y_{j-1}) pt's BSDF sampling toward it.
        const float pe_prev = pt.bsdf.PDF(wo_local, wi_local) * q.prev_convert;
        const float rl = Remap0(pe_prev) / Remap0(q.prev_pdf_fwd);
        total += rl * rl * q.prev_sum;
        return vm * vm / total;
    }

    void Load(const std::string& product) {
        Header h;
        if (product.size() < sizeof(Header) || std::memcmp(product.data(), kMagic, 4) != 0)
            throw std::invalid_argument("vcm: the scene product is not a vcm light-vertex grid");
        std::memcpy(&h, product.data(), sizeof(Header));
        if (h.light_paths != light_paths_ || h.merging != (merging_ ? 1u : 0u) || h.grow != (grow_ ? 1u : 0u) ||
            h.first_merge != uint32_t(first_merge_) || h.paths != IterationPaths(h.iteration))
            throw std::invalid_argument("vcm: the scene product was made with other settings");
        if (!h.merging) {
            if (product.size() != sizeof(Header)) throw std::invalid_argument("vcm: the scene product has the wrong size");
            return;
        }
        if (h.time_slices < 1 || h.time_slices > std::min(kMaxShutterSlices, h.paths))
            throw std::invalid_argument("vcm: the scene product's time slices are out of range");
        grid_ = PointHashGrid<LightVertex>::Deserialize(product.data() + sizeof(Header), product.size() - sizeof(Header));
        slices_ = ShutterSlices{h.time_slices};
        for (uint32_t b = 0; b < h.time_slices; ++b)
            slice_eta_.push_back(float(slices_.Paths(h.paths, b)) * kPi * h.radius * h.radius);
    }

    int max_depth_;
    uint32_t light_paths_;
    uint32_t max_iteration_paths_;
    float radius_, alpha_;
    bool merging_, grow_;
    int first_merge_;  // 2: direct light (y_1) is not merged; 1: it is (direct_merging)
    uint32_t time_slices_;  // K_1
    PointHashGrid<LightVertex> grid_;
    ShutterSlices slices_;  // the product's
    std::vector<float> slice_eta_;  // n_b pi r_i^2 per time slice; empty without merging
};

}  // namespace

IntegratorEntry VCMIntegratorEntry() {
    return {VCMIntegrator::Info, [](const IntegratorSettings& s, const Scene& scene) -> std::unique_ptr<Integrator> {
                const float paths = s.Param("light_paths", kDefaultLightPaths);
                if (!(paths >= 1.f && paths <= 4e6f && paths == std::floor(paths)))
                    throw std::invalid_argument(
                        "vcm light_paths must be a whole number from 1 to 4e6 (each keeps its merging vertices, "
                        "56 bytes each, in a product kept in Redis)");
                const float max_paths = s.Param("max_iteration_paths", float(kMaxLightPathsPerIteration));
                if (!(max_paths >= 1.f && max_paths <= float(kMaxLightPathsPerIteration) &&
                      max_paths == std::floor(max_paths)))
                    throw std::invalid_argument("vcm max_iteration_paths must be a whole number from 1 to 4e6");
                const float radius = s.Param("radius", kDefaultRadiusOfDiameter * 2.f * scene.scene_radius());
                if (!(radius > 0.f && std::isfinite(radius)))
                    throw std::invalid_argument("vcm radius must be a finite number > 0");
                const float alpha = s.Param("alpha", kDefaultAlpha);
                if (!(alpha > 0.f && alpha < 1.f))
                    throw std::invalid_argument("vcm alpha must lie strictly between 0 and 1");
                const float merging = s.Param("merging", 1.f);
                if (merging != 0.f && merging != 1.f) throw std::invalid_argument("vcm merging must be 0 or 1");
                const float grow = s.Param("grow", 1.f);
                if (grow != 0.f && grow != 1.f) throw std::invalid_argument("vcm grow must be 0 or 1");
                const float direct = s.Param("direct_merging", 0.f);
                if (direct != 0.f && direct != 1.f) throw std::invalid_argument("vcm direct_merging must be 0 or 1");
                if (s.max_depth > 65535) throw std::invalid_argument("vcm max_depth must be at most 65535");
                return std::make_unique<VCMIntegrator>(s.max_depth, uint32_t(paths), uint32_t(max_paths), radius,
                                                       alpha, merging == 1.f, grow == 1.f, direct == 1.f,
                                                       TimeSlicesSetting(s, "vcm"), s.scene_product);
            }};
}

}  // namespace tessera
