#include "libmodel/label_conventions.h"

#include "libmodel/text.h"

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
    c.pulmonary_artery = codes[6];
    c.blood = {codes[1], codes[2], codes[3], codes[4], codes[5], codes[6]};
    c.labelled_walls = "its myocardium is the left ventricle's wall with the septum; the right ventricle's free wall and the atria's "
                       "and great vessels' walls are not labelled";
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
        hvsmr.labelled_walls = "one myocardium label and one blood pool; much of the atria's and great vessels' blood has no wall labelled";
        all.push_back(hvsmr);
        all.push_back(mmwhs("mmwhs", "MM-WHS 2017", {205, 420, 500, 550, 600, 820, 850}));
        all.push_back(mmwhs("mmwhs-ordinal", "MM-WHS 2017 numbered 1-7", {1, 2, 3, 4, 5, 6, 7}));
        return all;
    }();
    return conventions;
}

std::vector<WallStructure> convention_walls(const LabelConvention& c, const WallThicknesses& t, int first_label) {
    std::vector<WallStructure> walls;
    auto add = [&](const char* name, std::vector<int> blood, double thickness) {
        walls.push_back({name, std::move(blood), thickness, first_label + int(walls.size())});
    };
    if (!c.chambers()) {  // one blood pool: one wall around it
        if (!c.blood.empty()) add("blood pool wall (grown)", c.blood, t.blood_pool);
        return walls;
    }
    add("right ventricle free wall (grown)", {c.right_ventricle}, t.right_ventricle);
    add("left ventricle wall (grown)", {c.left_ventricle}, t.left_ventricle);
    add("left atrium wall (grown)", {c.left_atrium}, t.atria);
    add("right atrium wall (grown)", {c.right_atrium}, t.atria);
    if (c.aorta) add("aortic wall (grown)", {c.aorta}, t.aorta);
    if (c.pulmonary_artery) add("pulmonary artery wall (grown)", {c.pulmonary_artery}, t.pulmonary_artery);
    return walls;
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
