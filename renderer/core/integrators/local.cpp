// Local shading (the lecture's method 1, L (D|S) E): primary visibility and direct light
// from every light with shadow rays, shaded by the material's BSDF, nothing reflected
// twice. It is the path tracer stopped after one scattering event, so it shares its code
// (and, on paths of one bounce, its exact estimates).
#include "path.h"

#include <algorithm>

namespace tessera {

namespace {

class LocalIntegrator final : public Integrator {
public:
    explicit LocalIntegrator(int max_depth) : path_(std::min(max_depth, 1)) {}
    static const IntegratorInfo& Info() {
        static const IntegratorInfo info{
            .name = "local",
            .description = "local shading: what the camera sees, lit directly by every light (one bounce)",
            .honours_light_links = true,  // path's kernel, one bounce
            .blind_to = {{"L D D+ E", "one bounce: surfaces get direct light only"},
                         {"L S+ E", "one bounce: a chain of mirror or glass reflections ends after its first"}},
        };
        return info;
    }
    const IntegratorInfo& info() const override { return Info(); }
    PathSample Sample(const Scene& scene, const Camera& camera, const CameraSample& cs, PixelSampler& sampler,
                      SplatFilm& film, IntegratorCounters* counters) const override {
        return path_.Sample(scene, camera, cs, sampler, film, counters);
    }

private:
    PathIntegrator path_;
};

}  // namespace

IntegratorEntry LocalIntegratorEntry() {
    return {LocalIntegrator::Info, [](const IntegratorSettings& s, const Scene&) -> std::unique_ptr<Integrator> {
                return std::make_unique<LocalIntegrator>(s.max_depth);
            }};
}

}  // namespace tessera
