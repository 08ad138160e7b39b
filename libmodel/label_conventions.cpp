#include "label_conventions.h"

#include "text.h"

#include <array>

namespace heartsim {

namespace {

/// MM-WHS's structures with the label values `codes` (myocardium, LA, LV, RA, RV, aorta, PA).
LabelConvention mmwhs(std::string name, std::string title, const std::array<int, 7>& codes) {
    LabelConvention c;
    c.name = std::move(name);
    c.title = std::move(title);
    // Names the segment classifier reads as they are meant: "blood pool" and "aorta"/"artery"
    // are not heart muscle, "myocardium" is (segment_names.h).
    const std::array<const char*, 7> names = {"myocardium",
                                              "left atrium blood pool",
                                              "left ventricle blood pool",
                                              "right atrium blood pool",
                                              "right ventricle blood pool",
                                              "ascending aorta",
                                              "pulmonary artery"};
    for (std::size_t k = 0; k < codes.size(); ++k) c.names[codes[k]] = names[k];
    c.myocardium = codes[0];
    c.left_atrium = codes[1];
    c.left_ventricle = codes[2];
    c.right_atrium = codes[3];
    c.right_ventricle = codes[4];
    c.aorta = codes[5];
    c.blood = {codes[1], codes[2], codes[3], codes[4], codes[5], codes[6]};
    return c;
}

}  // namespace

const std::vector<LabelConvention>& label_conventions() {
    static const std::vector<LabelConvention> conventions = [] {
        std::vector<LabelConvention> all;
        LabelConvention hvsmr;
        hvsmr.name = "hvsmr2016";
        hvsmr.title = "HVSMR 2016";
        hvsmr.names = {{1, "myocardium"}, {2, "blood pool"}};
        hvsmr.myocardium = 1;
        hvsmr.blood = {2};
        all.push_back(hvsmr);
        all.push_back(mmwhs("mmwhs", "MM-WHS 2017", {205, 420, 500, 550, 600, 820, 850}));
        all.push_back(mmwhs("mmwhs-ordinal", "MM-WHS 2017 numbered 1-7", {1, 2, 3, 4, 5, 6, 7}));
        return all;
    }();
    return conventions;
}

const LabelConvention* find_label_convention(const std::string& name) {
    const std::string wanted = text::lowercase(text::trim(name));
    for (const LabelConvention& c : label_conventions())
        if (c.name == wanted) return &c;
    return nullptr;
}

std::string label_convention_names() {
    std::string out;
    for (const LabelConvention& c : label_conventions()) out += (out.empty() ? "" : ", ") + c.name;
    return out;
}

const LabelConvention* matching_label_convention(const std::set<int>& present) {
    for (const LabelConvention& c : label_conventions()) {
        std::set<int> labels;
        for (const auto& entry : c.names) labels.insert(entry.first);
        if (labels == present) return &c;
    }
    return nullptr;
}

}  // namespace heartsim
