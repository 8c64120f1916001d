// The list of BSDF kinds, written once. A kind is its own file in bsdfs/ (its f, Sample_f,
// PDF, Flags and Albedo, and its kName) plus one line in BSDFKinds below. From this list
// come the variant the BSDF an integrator holds is made of (bsdf.h), its dispatch, the
// kind numbers and the names the Python side asks the core for
// (tessera_renderer._core.bsdf_kinds()): nothing else lists the kinds.
//
// The dispatch stays a std::visit over that variant, not a virtual call: the compiler
// turns it into a switch on the variant's index with every kind's call inlined or called
// directly, as the hand-written variant was.
#pragma once

#include <cstddef>
#include <type_traits>
#include <variant>
#include <vector>

#include "conductor_bsdf.h"
#include "dielectric_bsdf.h"
#include "diffuse_bsdf.h"
#include "feature_set.h"
#include "preview_surface_bsdf.h"

namespace tessera {

template <typename... Kinds>
struct BSDFKindList {
    static constexpr size_t kCount = sizeof...(Kinds);
    using Variant = std::variant<Kinds...>;
};

// Every BSDF kind, in kind-number order. The first is the default (a black one is what
// light-only geometry scatters with) and the only one of the Lambert-only build.
using BSDFKinds = BSDFKindList<DiffuseBSDF, ConductorBSDF, DielectricBSDF, PreviewSurfaceBSDF>;

// The kinds this build can hold: the Lambert-only build (feature_set.h) keeps the first.
using BuiltBSDFKinds = std::conditional_t<kFullFeatures, BSDFKinds, BSDFKindList<DiffuseBSDF>>;

namespace bsdf_kinds_detail {
template <typename K, typename... Ks>
constexpr size_t IndexOf(BSDFKindList<Ks...>) {
    constexpr bool same[] = {std::is_same_v<K, Ks>...};
    for (size_t i = 0; i < sizeof...(Ks); ++i)
        if (same[i]) return i;
    return sizeof...(Ks);
}
template <typename F, typename... Ks>
inline void ForEach(F& f, BSDFKindList<Ks...>) {
    (f(static_cast<const Ks*>(nullptr)), ...);
}
}  // namespace bsdf_kinds_detail

// Whether K is a kind of BSDFKinds, and its number there.
template <typename K>
inline constexpr bool kIsBSDFKind = bsdf_kinds_detail::IndexOf<K>(BSDFKinds{}) < BSDFKinds::kCount;
template <typename K>
inline constexpr size_t kBSDFKindOf = [] {
    static_assert(kIsBSDFKind<K>, "not a BSDF kind: add it to BSDFKinds");
    return bsdf_kinds_detail::IndexOf<K>(BSDFKinds{});
}();

// f(static_cast<const K*>(nullptr)) for every kind K, in kind order.
template <typename F>
inline void ForEachBSDFKind(F&& f) {
    bsdf_kinds_detail::ForEach(f, BSDFKinds{});
}

// The kinds' names (K::kName) by kind number.
inline std::vector<const char*> BSDFKindNames() {
    std::vector<const char*> names;
    ForEachBSDFKind([&](auto* kind) { names.push_back(std::remove_pointer_t<decltype(kind)>::kName); });
    return names;
}

}  // namespace tessera
