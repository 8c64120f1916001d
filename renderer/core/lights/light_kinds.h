// The list of light kinds, written once. A kind is its own file in lights/ (what it stores,
// how it is sampled, what it emits and with what densities, as an emitter of the Scene)
// plus one line in LightKinds below. From this list come the LightKind numbers, the
// Scene's per-kind storage (lights and their motion), the switch statements of the
// Scene's emitter queries (VisitLightKind) and the names the Python side asks the core for
// (tessera_renderer._core.light_kinds()): nothing else lists the kinds.
//
// The dispatch stays a tag switch, not a virtual call: VisitLightKind unrolls into a chain
// of compares on the emitter's kind byte that the compiler turns into the same jump the
// hand-written switch statements were, and every kind's code inlines into it.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <tuple>
#include <type_traits>
#include <vector>

#include "distant_light.h"
#include "dome_light.h"
#include "light.h"
#include "point_light.h"
#include "portal_light.h"
#include "sphere_light.h"
#include "triangle_light.h"

namespace tessera {

template <typename... Kinds>
struct LightKindList {
    static constexpr size_t kCount = sizeof...(Kinds);
};

// Every light kind, in LightKind order (a moving light names its kind by this number).
using LightKinds = LightKindList<TriangleLight, SphereLight, PointLight, DistantLight, DomeLight, PortalLight>;

namespace light_kinds_detail {
template <typename K, typename... Ks>
constexpr size_t IndexOf(LightKindList<Ks...>) {
    constexpr bool same[] = {std::is_same_v<K, Ks>...};
    for (size_t i = 0; i < sizeof...(Ks); ++i)
        if (same[i]) return i;
    return sizeof...(Ks);
}
}  // namespace light_kinds_detail

// The LightKind number of kind K.
template <typename K>
inline constexpr LightKind kKindOf = [] {
    constexpr size_t i = light_kinds_detail::IndexOf<K>(LightKinds{});
    static_assert(i < LightKinds::kCount, "not a light kind: add it to LightKinds");
    return LightKind(i);
}();

template <typename K>
struct KindTag {
    using type = K;
};

namespace light_kinds_detail {
template <size_t I, typename F, typename K, typename... Rest>
inline decltype(auto) VisitAt(uint8_t kind, F& f) {
    if constexpr (sizeof...(Rest) == 0) {
        return f(KindTag<K>{});  // the last kind: a valid kind byte can only be this one
    } else {
        if (kind == I) return f(KindTag<K>{});
        return VisitAt<I + 1, F, Rest...>(kind, f);
    }
}
template <typename F, typename... Ks>
inline decltype(auto) Visit(LightKind kind, F& f, LightKindList<Ks...>) {
    return VisitAt<0, F, Ks...>(uint8_t(kind), f);
}
template <typename F, typename... Ks>
inline void ForEach(F& f, LightKindList<Ks...>) {
    (f(KindTag<Ks>{}), ...);
}
template <template <typename> class Slot, typename... Ks>
std::tuple<Slot<Ks>...> TupleOf(LightKindList<Ks...>);
}  // namespace light_kinds_detail

// f(KindTag<K>{}) for the kind `kind` names; every branch must return the same type.
template <typename F>
inline decltype(auto) VisitLightKind(LightKind kind, F&& f) {
    return light_kinds_detail::Visit(kind, f, LightKinds{});
}

// f(KindTag<K>{}) for every kind, in LightKind order.
template <typename F>
inline void ForEachLightKind(F&& f) {
    light_kinds_detail::ForEach(f, LightKinds{});
}

// One Slot<K> per kind, e.g. the Scene's lights of each kind (PerLightKind<std::vector>).
template <template <typename> class Slot>
class PerLightKind {
public:
    template <typename K>
    Slot<K>& Of() {
        return std::get<size_t(kKindOf<K>)>(slots_);
    }
    template <typename K>
    const Slot<K>& Of() const {
        return std::get<size_t(kKindOf<K>)>(slots_);
    }

private:
    decltype(light_kinds_detail::TupleOf<Slot>(LightKinds{})) slots_;
};

// What a kind may declare beyond the queries every kind answers, each with its default:
// - kRowColumns and FromRow(const float*): its lights come from the binding as rows of
//   that many floats (SceneDesc::light_rows), the first three the light's position; a
//   new kind hands its lights over this way, with nothing restated per kind on the route.
// - kStartsLightPaths = false: SampleEmission cannot start a light subpath from it, and
//   the integrators that trace those refuse the scene (Integrator::Create).
// - using Guides = OtherKind: its lights carry OtherKind's light (portals the dome's);
//   when the scene has any, OtherKind adds no emitters of its own.
template <typename K>
inline constexpr size_t kRowColumnsOf = [] {
    if constexpr (requires { EmitterOf<K>::kRowColumns; }) return size_t(EmitterOf<K>::kRowColumns);
    else return size_t(0);
}();
template <typename K>
inline constexpr bool kStartsLightPathsOf = [] {
    if constexpr (requires { EmitterOf<K>::kStartsLightPaths; }) return bool(EmitterOf<K>::kStartsLightPaths);
    else return true;
}();
template <typename K, typename Guided>
inline constexpr bool kGuides = [] {
    if constexpr (requires { typename EmitterOf<K>::Guides; })
        return std::is_same_v<typename EmitterOf<K>::Guides, Guided>;
    else return false;
}();

// The kinds' names (EmitterOf<K>::kName) by LightKind number, whether a light of the kind
// can move rigidly (SceneDesc::light_motion_kinds; triangles move with their meshes), and
// the columns of its rows when it is handed over in rows (0: it is not).
struct LightKindInfo {
    const char* name;
    bool moves;
    size_t row_columns;
};
inline std::vector<LightKindInfo> LightKindInfos() {
    std::vector<LightKindInfo> infos;
    ForEachLightKind([&](auto tag) {
        using Kind = typename decltype(tag)::type;
        infos.push_back({EmitterOf<Kind>::kName, EmitterOf<Kind>::kMoves, kRowColumnsOf<Kind>});
    });
    return infos;
}
// "1 sphere, 2 point, ..." for error messages: the kinds a moving light can be, by number.
inline std::string MovingKindNames() {
    const std::vector<LightKindInfo> infos = LightKindInfos();
    std::string names;
    for (size_t k = 0; k < infos.size(); ++k)
        if (infos[k].moves) names += (names.empty() ? "" : ", ") + std::to_string(k) + " " + infos[k].name;
    return names;
}

}  // namespace tessera
