// What every BSDF kind shares: the conventions it follows, the sample it returns and the
// flags it answers with. A kind is its own file (diffuse_bsdf.h, ...) listed in
// bsdf_kinds.h; the BSDF an integrator holds (bsdf.h) dispatches to it.
//
// Conventions (pbrt-v4's, so the book's integrators carry over):
//  * wo and wi are unit vectors pointing AWAY from the surface, in the local shading frame
//    (z = shading normal); wo is toward the camera (TransportMode::Radiance) or toward the
//    light (Importance).
//  * f(wo, wi) is the BSDF value WITHOUT the cosine; the integrator multiplies |wi.z|.
//  * PDF(wo, wi) is the solid-angle density of Sample_f producing wi, counting only the
//    non-delta lobes. f and PDF are 0 for any wi a delta lobe could produce.
//  * Sample_f returns, for a delta lobe, is_specular = true, pdf = the discrete probability
//    of having chosen that lobe, and f such that f |wi.z| / pdf is the sample's weight.
//    For a non-delta sample, f == f(wo, wi) and pdf == PDF(wo, wi) (the full mixture), so
//    MIS against light sampling works unchanged.
//  * Opaque BSDFs (Diffuse, Conductor, PreviewSurface's opaque lobes) are two-sided: wo
//    below the horizon is mirrored to the upper hemisphere, because USD meshes are often
//    single sheets. DielectricBSDF is sided: wo.z > 0 is outside (index 1), wo.z < 0 is
//    inside (index ior).
//  * wo exactly on the horizon (wo.z == 0) scatters nothing: f = 0, PDF = 0, no sample.
//
// TransportMode: Radiance BSDFs divide transmission by eta² (radiance is compressed into
// a smaller solid angle when entering a denser medium, Veach 1997 §5.2); Importance (light
// tracing, BDPT light subpaths) does not. f_Importance(wo, wi) == f_Radiance(wi, wo).
#pragma once

#include <cstdint>

#include "math.h"

namespace tessera {

enum class TransportMode { Radiance, Importance };

enum BSDFFlags : uint32_t {
    kBSDFUnset = 0,
    kBSDFReflection = 1u << 0,
    kBSDFTransmission = 1u << 1,
    kBSDFDiffuse = 1u << 2,
    kBSDFGlossy = 1u << 3,
    kBSDFSpecular = 1u << 4,  // a delta lobe
};

struct BSDFSample {
    Color f;
    Vec3 wi;
    float pdf = 0.f;
    bool is_specular = false;      // sampled from a delta lobe
    bool is_transmission = false;  // wi on the other side of the surface from wo
    // Relative index of refraction n_wi_side / n_wo_side for transmission, 1 for reflection.
    // An integrator tracks the product of eta² over the path to keep Russian roulette from
    // reacting to the radiance scaling (pbrt-v4's etaScale).
    float eta = 1.f;
};

// The two-sided kinds bring wo to the upper hemisphere by mirroring z, and the smooth
// lobes reflect about the normal.
inline Vec3 FlipZ(Vec3 w) { return {w.x, w.y, -w.z}; }
inline Vec3 MirrorAboutNormal(Vec3 w) { return {-w.x, -w.y, w.z}; }

}  // namespace tessera
