// What this build of the renderer can render.
//
// The full build has every feature, and a scene pays for the features it lacks only with
// runtime tests that skip them (a flag per scene, material or camera, tested where the
// feature would act). The CMake option TESSERA_LAMBERT_ONLY builds a renderer that can
// render nothing but Lambertian triangles lit by triangle area lights through a pinhole
// camera, with those tests compiled out (`if (kFullFeatures && ...)`), and BSDF holding
// only DiffuseBSDF. It exists to measure what the full build's generality costs such a
// scene (benchmarks/lambert_only.py); its Scene and RenderTile refuse anything else.
#pragma once

namespace tessera {

#ifdef TESSERA_LAMBERT_ONLY
inline constexpr bool kFullFeatures = false;
#else
inline constexpr bool kFullFeatures = true;
#endif

}  // namespace tessera
