// Chooses an emitter with probability proportional to its power (Walker's alias method:
// O(1) per sample). Powers of zero are never chosen.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <vector>

namespace tessera {

class LightSampler {
public:
    LightSampler() = default;
    explicit LightSampler(const std::vector<double>& power) {
        double total = 0.0;
        for (double p : power) {
            if (!(p >= 0.0) || !std::isfinite(p)) throw std::invalid_argument("emitter power must be finite and >= 0");
            total += p;
        }
        const size_t n = power.size();
        if (n == 0 || total <= 0.0) return;
        pmf_.resize(n);
        prob_.assign(n, 1.f);
        alias_.resize(n);
        std::vector<double> scaled(n);
        std::vector<uint32_t> small, large;
        for (size_t i = 0; i < n; ++i) {
            pmf_[i] = float(power[i] / total);
            scaled[i] = power[i] / total * double(n);
            alias_[i] = uint32_t(i);
            (scaled[i] < 1.0 ? small : large).push_back(uint32_t(i));
        }
        while (!small.empty() && !large.empty()) {
            uint32_t s = small.back(), l = large.back();
            small.pop_back();
            prob_[s] = float(scaled[s]);
            alias_[s] = l;
            scaled[l] = (scaled[l] + scaled[s]) - 1.0;
            if (scaled[l] < 1.0) {
                large.pop_back();
                small.push_back(l);
            }
        }
        // Leftovers are 1 up to rounding; they keep prob 1 and alias themselves.
    }

    bool empty() const { return pmf_.empty(); }
    size_t size() const { return pmf_.size(); }
    float Pmf(uint32_t i) const { return i < pmf_.size() ? pmf_[i] : 0.f; }

    // u in [0, 1). Returns the emitter index and writes its probability.
    uint32_t Sample(float u, float* pmf) const {
        const size_t n = pmf_.size();
        float scaled = u * float(n);
        uint32_t bin = std::min(uint32_t(scaled), uint32_t(n - 1));
        float remainder = scaled - float(bin);
        uint32_t i = remainder < prob_[bin] ? bin : alias_[bin];
        *pmf = pmf_[i];
        return i;
    }

private:
    std::vector<float> pmf_, prob_;
    std::vector<uint32_t> alias_;
};

}  // namespace tessera
