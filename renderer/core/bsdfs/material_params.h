// The UsdPreviewSurface inputs a path tracer honours, with the spec's defaults, and the
// rules that read them before any BSDF is built (sanitising, cutout and presence modes).
#pragma once

#include <algorithm>
#include <cmath>

#include "math.h"

namespace tessera {

struct MaterialParams {
    Color diffuse_color = Color(0.18f);
    Color emissive_color = Color(0.f);  // not part of the BSDF: the integrator adds it
    bool use_specular_workflow = false;
    Color specular_color = Color(0.f);
    float metallic = 0.f;
    float roughness = 0.5f;
    float clearcoat = 0.f;
    float clearcoat_roughness = 0.01f;
    float opacity = 1.f;
    float opacity_threshold = 0.f;
    float ior = 1.5f;
    // Multiplies transmission through a fully transmissive surface (opacity 0): the colour
    // of MaterialX transmission at depth 0, applied at each crossing. 1: clear.
    Color transmission_tint = Color(1.f);
};

// Out-of-range inputs are sanitised where they are read, never propagated as NaN.
inline float Clamp01(float v) { return std::isfinite(v) ? std::clamp(v, 0.f, 1.f) : 0.f; }
inline Color Clamp01(Color c) { return {Clamp01(c.x), Clamp01(c.y), Clamp01(c.z)}; }
// A non-finite or non-positive ior reads as the spec's default 1.5.
inline float SanitisedIor(const MaterialParams& p) { return std::isfinite(p.ior) && p.ior > 0.f ? p.ior : 1.5f; }

// Cutout mode (opacityThreshold > 0): a hit whose opacity (the material's, or a texture's
// at that point) is below the threshold is not a surface at all; the integrator continues
// the ray (and shadow rays) through it. Never true when opacity_threshold == 0.
inline bool IsCutout(const MaterialParams& p, float opacity) {
    return p.opacity_threshold > 0.f && opacity < p.opacity_threshold;
}

// Presence mode (opacity_threshold < 0, which USD cannot mean: the translator's mark for a
// partial opacity that asks for no refraction): opacity is the probability that a hit is a
// surface at all, and the BSDF of the hits that are is opaque. The other hits pass
// straight through, camera and shadow rays alike (Scene::IsCutoutHit decides each one).
inline bool IsPresenceMode(const MaterialParams& p) { return p.opacity_threshold < 0.f; }

}  // namespace tessera
