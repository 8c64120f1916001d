// UsdLux light linking and shadow linking as the core sees them. A light's
// collection:lightLink names the geometry it illuminates, its collection:shadowLink the
// geometry that casts its shadows. Translation sorts the scene's surfaces into link groups
// (the surfaces every such collection treats alike: Material::link_group) and gives each
// light with a collection that leaves something out a link number (-1: the default, which
// illuminates everything and is shadowed by everything). A link's row then says, per group,
// whether the light illuminates it and whether it casts the light's shadows.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace tessera {

class LightLinkTable {
public:
    LightLinkTable() = default;
    // illuminates and casts_shadow: num_links rows of num_groups flags (0/1), row-major.
    LightLinkTable(uint32_t num_groups, std::vector<uint8_t> illuminates, std::vector<uint8_t> casts_shadow)
        : num_groups_(num_groups), illuminates_(std::move(illuminates)), casts_shadow_(std::move(casts_shadow)) {
        if (num_groups_ == 0 ? !illuminates_.empty() : illuminates_.size() % num_groups_ != 0)
            throw std::invalid_argument("light links: the illumination table needs a row of flags per link group");
        if (casts_shadow_.size() != illuminates_.size())
            throw std::invalid_argument("light links: the shadow table must have the illumination table's shape");
        const size_t links = num_groups_ ? illuminates_.size() / num_groups_ : 0;
        shadow_excludes_.assign(links, 0);
        for (size_t l = 0; l < links; ++l)
            for (uint32_t g = 0; g < num_groups_; ++g)
                if (!casts_shadow_[l * num_groups_ + g]) shadow_excludes_[l] = 1;
    }

    bool empty() const { return illuminates_.empty(); }
    uint32_t num_groups() const { return num_groups_; }
    size_t num_links() const { return shadow_excludes_.size(); }
    // link < 0 is the default link (everything); group < num_groups() for any other.
    bool Illuminates(int32_t link, uint32_t group) const {
        return link < 0 || illuminates_[size_t(link) * num_groups_ + group];
    }
    bool CastsShadow(int32_t link, uint32_t group) const {
        return link < 0 || casts_shadow_[size_t(link) * num_groups_ + group];
    }
    // Some group does not cast the link's shadows: its shadow rays must look past such
    // surfaces, which a BSDF-sampled ray (stopping at the first surface) cannot.
    bool ExcludesShadows(int32_t link) const { return link >= 0 && shadow_excludes_[size_t(link)]; }

    // A light's link number checked against the table (throws naming `what`).
    void Check(int32_t link, const std::string& what) const {
        if (link < -1 || (link >= 0 && size_t(link) >= num_links()))
            throw std::invalid_argument(what + " has light link " + std::to_string(link) + " of " +
                                        std::to_string(num_links()));
    }

private:
    uint32_t num_groups_ = 0;
    std::vector<uint8_t> illuminates_, casts_shadow_;
    std::vector<uint8_t> shadow_excludes_;  // per link
};

}  // namespace tessera
