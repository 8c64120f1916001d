#include "bsdf.h"

#include "fresnel.h"
#include "microfacet.h"

namespace tessera {

std::optional<Color> ExactLambertianAlbedo(const MaterialParams& p) {
    // Opaque at every hit: the BSDF's own opacity rule, and no cutout or presence holes.
    const bool opaque = p.opacity_threshold == 0.f   ? Clamp01(p.opacity) == 1.f
                        : p.opacity_threshold > 0.f ? !IsCutout(p, p.opacity)
                                                    : p.opacity >= 1.f;
    if (!opaque || Clamp01(p.clearcoat) > 0.f) return std::nullopt;
    const Color base = Clamp01(p.diffuse_color);
    if (p.use_specular_workflow) {
        // F0 = specularColor, F90 = min(1, 50 max F0): both 0 only when F0 is.
        if (!IsBlack(Clamp01(p.specular_color))) return std::nullopt;
        return base;
    }
    const float ior = SanitisedIor(p);
    if (Clamp01(p.metallic) != 0.f || F0FromIor(ior) != 0.f) return std::nullopt;
    return base;
}

BSDF MakePreviewSurfaceBSDF(const MaterialParams& p, TransportMode mode) {
    const bool cutout_mode = p.opacity_threshold != 0.f;  // or presence mode: opaque where hit
    const float opacity = cutout_mode ? 1.f : Clamp01(p.opacity);
    const float ior = SanitisedIor(p);
    const float alpha = TrowbridgeReitz::RoughnessToAlpha(p.roughness);
    if (opacity == 0.f) return DielectricBSDF(ior, alpha, mode, Clamp01(p.transmission_tint));
    const bool no_coat = !(Clamp01(p.clearcoat) > 0.f);
    if (opacity == 1.f && no_coat && !p.use_specular_workflow && Clamp01(p.metallic) == 1.f) {
        Color c = Clamp01(p.diffuse_color);
        return ConductorBSDF(c, c, alpha);
    }
    return PreviewSurfaceBSDF(p, mode);
}

}  // namespace tessera
