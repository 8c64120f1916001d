// A heterogeneous medium: absorption and scattering coefficients per RGB channel per unit
// of density, times a voxel grid's density (density_grid.h), and a Henyey-Greenstein g.
//
// Null-scattering tracking against the grid's per-block maxima (pbrt-v4's majorant grid),
// keeping media/medium.h's two choices: free flights sample scattering only, absorption
// being a weight, and chromatic coefficients use the path's hero channel.
//  - Free flights: delta tracking of the hero's scattering coefficient (tentative
//    collisions at the block majorant k_h D_max, real with probability D / D_max). As a
//    null-collision path integral with each channel's own majorant k_c D_max, every
//    channel's integrand equals its sampling density (the density is one scalar field, so
//    a collision is null for all channels alike), and the densities over the hero's are
//    (k_c / k_h)^n e^(-(k_c - k_h) M): n tentative collisions, M the majorant's integral.
//    The absorption weight e^(-sigma_a * integral of D) is estimated by residual ratio
//    tracking (below) over the distance flown. A constant grid therefore samples exactly
//    as the homogeneous medium of its density, with an exact absorption weight.
//  - Transmittance (shadow rays, absorption): residual ratio tracking (Novak et al. 2014)
//    per block, control D_min, residual majorant max_c(k_c) (D_max - D_min): unbiased, and
//    exact in constant blocks, where plain ratio tracking is a binary estimate.
// Tracking draws a variable number of random numbers, so it takes them from a small
// generator seeded by the segment (the sampler's one dimension per segment and the ray),
// as pbrt-v4 does: the image stays a function of (scene, pixel, sample, seed).
#pragma once

#include <cstdint>
#include <memory>

#include "density_grid.h"
#include "medium.h"

namespace tessera {

struct GridMedium {
    Color sigma_a;  // absorption per unit length per unit density, per channel
    Color sigma_s;  // scattering per unit length per unit density, per channel
    float g = 0.f;
    std::shared_ptr<DensityGrid> grid;

    Color sigma_t() const { return sigma_a + sigma_s; }
    bool Valid() const { return grid && HomogeneousMedium{sigma_a, sigma_s, g}.Valid(); }
};

// A small generator for tracking (SplitMix64 over a seed).
class TrackingRng {
public:
    explicit TrackingRng(uint64_t seed) : state_(seed) {}
    // Uniform in [0, 1).
    float Uniform() { return float(Next() >> 40) * 0x1p-24f; }

private:
    uint64_t Next() {
        uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    uint64_t state_;
};

// A seed from a ray and a variate: the same ray and variate give the same tracking.
uint64_t TrackingSeed(Vec3 o, Vec3 d, float u);

// A free flight along the world ray o + t d, t in [0, t_max] (t_max may be +inf), as
// SampleFreeFlight of medium.h. `pdf` holds each channel's density over the hero's (the
// hero's entry is 1), `f` those times the absorption weight.
MediumSample SampleFreeFlight(const GridMedium& m, Vec3 o, Vec3 d, float t_max, int hero, float u);

// An unbiased estimate of e^(-k_c * integral of the density) per channel along o + t d,
// t in [t0, t1], by residual ratio tracking.
Color EstimateTransmittance(const GridMedium& m, Color k, Vec3 o, Vec3 d, float t0, float t1, TrackingRng& rng);

}  // namespace tessera
