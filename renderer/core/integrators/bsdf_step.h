// BSDF sampling that continues a path at a surface vertex, shared by the kernels that extend
// paths this way (path, its lane and media kernels, hybrid, and the light tracer's two). Every caller draws the
// same dimensions in the same order (the lobe choice, 1D, then the direction, 2D), so
// kernels that share a sample stream stay bit for bit alike.
#pragma once

#include <cmath>
#include <optional>

#include "bsdf.h"
#include "sampler.h"
#include "scene.h"

namespace tessera {

struct BSDFStep {
    BSDFSample sample;
    Vec3 wi;  // the sampled direction in world space, unit length
};

// nullopt ends the path: no sample, a zero pdf or value, or a direction that the geometric
// normal `ng` puts on another side than the shading frame does (SidesAgree). Otherwise
// `beta` has been multiplied by f |cos theta_i| / pdf, times shading_correction(wi): a light
// path (importance transport) passes ImportanceShadingCorrection there, the adjoint BSDF's
// shading-normal factor (Veach 1997, 5.3); a camera path passes nothing (1, exactly).
template <typename Shading, typename Correction>
inline std::optional<BSDFStep> SampleBSDFStep(const Shading& bsdf, const Frame& frame, Vec3 wo, Vec3 wo_local,
                                              Vec3 ng, PixelSampler& sampler, Color& beta,
                                              Correction shading_correction) {
    const float uc = sampler.Get1D();
    const std::optional<BSDFSample> bs = bsdf.Sample_f(wo_local, uc, sampler.Get2D());
    if (!bs || !(bs->pdf > 0.f) || IsBlack(bs->f)) return std::nullopt;
    const Vec3 wi = Normalize(frame.FromLocal(bs->wi));
    if (!SidesAgree(wo, wi, ng, wo_local, bs->wi)) return std::nullopt;
    beta *= bs->f * (std::abs(bs->wi.z) / bs->pdf * shading_correction(wi));
    return BSDFStep{*bs, wi};
}

template <typename Shading>
inline std::optional<BSDFStep> SampleBSDFStep(const Shading& bsdf, const Frame& frame, Vec3 wo, Vec3 wo_local,
                                              Vec3 ng, PixelSampler& sampler, Color& beta) {
    return SampleBSDFStep(bsdf, frame, wo, wo_local, ng, sampler, beta, [](Vec3) { return 1.f; });
}

}  // namespace tessera
