// The integrator registry: one line per integrator in TESSERA_INTEGRATORS. The list is
// explicit because a static library's linker drops object files nothing references, which
// would silently unregister self-registering integrators.
//
// Order matters twice: it is the order integrators are listed in, and `auto` prefers the
// earlier of two complete integrators (path is measured the more efficient per unit time
// where both apply: docs/benchmarks/integrators.md).
#include <algorithm>
#include <iterator>
#include <stdexcept>
#include <string>

#include "integrator.h"

#define TESSERA_INTEGRATORS(X) \
    X(PathIntegratorEntry)     \
    X(BDPTIntegratorEntry)     \
    X(LightTracerEntry)        \
    X(WhittedIntegratorEntry)  \
    X(LocalIntegratorEntry)    \
    X(AOIntegratorEntry)       \
    X(PhotonDirectIntegratorEntry) \
    X(PhotonIntegratorEntry)       \
    X(SPPMIntegratorEntry)         \
    X(VCMIntegratorEntry)          \
    X(RadiosityIntegratorEntry)    \
    X(HybridIntegratorEntry)

namespace tessera {

#define TESSERA_DECLARE_ENTRY(entry) IntegratorEntry entry();
TESSERA_INTEGRATORS(TESSERA_DECLARE_ENTRY)
#undef TESSERA_DECLARE_ENTRY

namespace {

const std::vector<IntegratorEntry>& Entries() {
#define TESSERA_LIST_ENTRY(entry) entry(),
    static const std::vector<IntegratorEntry> entries{TESSERA_INTEGRATORS(TESSERA_LIST_ENTRY)};
#undef TESSERA_LIST_ENTRY
    return entries;
}

std::string KnownNames() {
    std::string names;
    for (const IntegratorEntry& e : Entries()) names += (names.empty() ? "" : ", ") + std::string(e.info().name);
    return names;
}

}  // namespace

const std::vector<IntegratorInfo>& RegisteredIntegrators() {
    static const std::vector<IntegratorInfo> infos = [] {
        std::vector<IntegratorInfo> v;
        for (const IntegratorEntry& e : Entries()) {
            // A misspelt class would silently let an integrator skip no scene at all.
            for (const PathExclusion& x : e.info().blind_to)
                if (std::find(std::begin(kPathClasses), std::end(kPathClasses), x.paths) == std::end(kPathClasses))
                    throw std::logic_error("integrator '" + std::string(e.info().name) + "' declares an unknown "
                                           "light-path class '" + std::string(x.paths) + "'");
            v.push_back(e.info());
        }
        return v;
    }();
    return infos;
}

const IntegratorInfo* FindIntegrator(std::string_view name) {
    for (const IntegratorEntry& e : Entries())
        if (e.info().name == name) return &e.info();
    return nullptr;
}

std::string_view AutoIntegrator(bool scene_has_delta_caustics) {
    for (const IntegratorEntry& e : Entries()) {
        const IntegratorInfo& info = e.info();
        if (info.complete && (info.delta_caustics || !scene_has_delta_caustics)) return info.name;
    }
    throw std::logic_error("no complete integrator is registered");
}

std::string Integrator::RunScenePass(const Scene&, uint32_t, uint32_t, int) const {
    throw std::invalid_argument("integrator '" + std::string(info().name) + "' has no scene-wide passes");
}

std::unique_ptr<Integrator> Integrator::Create(std::string_view name, const IntegratorSettings& settings,
                                               const Scene& scene) {
    for (const IntegratorEntry& e : Entries()) {
        const IntegratorInfo& info = e.info();
        if (info.name != name) continue;
        for (const auto& [param, value] : settings.params) {
            bool known = false;
            std::string names;
            for (const IntegratorParam& p : info.params) {
                known = known || p.name == param;
                names += (names.empty() ? "" : ", ") + std::string(p.name);
            }
            if (!known)
                throw std::invalid_argument("integrator '" + std::string(name) + "' has no setting '" + param +
                                            "' (" + (names.empty() ? "it takes none" : "known: " + names) + ")");
        }
        if (scene.has_media() && !info.handles_media)
            throw std::invalid_argument("the " + std::string(name) + " integrator does not render participating "
                                        "media, and the scene has some (docs/media.md): render it with path");
        if (scene.num_grid_media() > 0 && !info.handles_grid_media)
            throw std::invalid_argument("the " + std::string(name) + " integrator does not render volumes (grid "
                                        "media), and the scene has some (docs/media.md): render it with path");
        if (info.traces_light_paths && scene.kind_without_light_paths())
            throw std::invalid_argument("the " + std::string(name) + " integrator starts paths at the lights, and " +
                                        scene.kind_without_light_paths() + " lights cannot start one yet "
                                        "(docs/scene-translation.md): render this scene with path");
        return e.create(settings, scene);
    }
    throw std::invalid_argument("unknown integrator '" + std::string(name) + "' (known: " + KnownNames() + ")");
}

}  // namespace tessera
