// BSDF sampling that continues a camera path at a surface vertex, shared by the kernels that
// extend paths this way (path, its lane and media kernels, hybrid). Every caller draws the
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
// `beta` has been multiplied by f |cos theta_i| / pdf.
template <typename Shading>
inline std::optional<BSDFStep> SampleBSDFStep(const Shading& bsdf, const Frame& frame, Vec3 wo, Vec3 wo_local,
                                              Vec3 ng, PixelSampler& sampler, Color& beta) {
    const float uc = sampler.Get1D();
    const std::optional<BSDFSample> bs = bsdf.Sample_f(wo_local, uc, sampler.Get2D());
    if (!bs || !(bs->pdf > 0.f) || IsBlack(bs->f)) return std::nullopt;
    const Vec3 wi = Normalize(frame.FromLocal(bs->wi));
    if (!SidesAgree(wo, wi, ng, wo_local, bs->wi)) return std::nullopt;
    beta *= bs->f * (std::abs(bs->wi.z) / bs->pdf);
    return BSDFStep{*bs, wi};
}

}  // namespace tessera
